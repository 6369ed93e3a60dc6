// Time conventions (docs/conventions.md): every exposure carries two clocks.
//  - TAI nanoseconds since 1970-01-01T00:00:00 TAI, from PTP (IEEE 1588 uses TAI), the time
//    base shared by all units and the FTI recorder;
//  - the unit's CLOCK_MONOTONIC nanoseconds, for local ordering and jitter measurement.
// Exposure time stamps mark the START of the exposure; the exposure mid-point is
// start + duration / 2 and is what the host aligns and interpolates on.
#pragma once

#include <cstdint>
#include <ctime>

namespace storetrack::time {

using TaiNs = std::int64_t;        ///< ns since 1970-01-01 TAI (PTP timescale)
using MonotonicNs = std::int64_t;  ///< ns of the unit's CLOCK_MONOTONIC

inline constexpr std::int64_t kNsPerSecond = 1'000'000'000;
/// TAI - UTC, in seconds, valid since 2017-01-01 (no leap second announced since).
inline constexpr std::int64_t kTaiMinusUtcSeconds = 37;

/// Clock state of a unit, as reported in every MarkObservations and UnitHealth message.
enum class ClockState : std::uint8_t {
  kFreeRunning = 0,  ///< no PTP: TAI is the unit's own estimate, not comparable across units
  kLocking = 1,      ///< PTP servo converging: offsets may still be microseconds
  kLocked = 2,       ///< PTP locked within the configured offset limit
  kHoldover = 3,     ///< lost the grandmaster; extrapolating the last lock
};

inline MonotonicNs monotonic_now_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<MonotonicNs>(ts.tv_sec) * kNsPerSecond + ts.tv_nsec;
}

/// The unit's best TAI estimate: CLOCK_TAI when the kernel's TAI offset is set (by ptp4l /
/// phc2sys), else CLOCK_REALTIME + 37 s.
inline TaiNs tai_now_ns() {
  timespec ts{};
  clock_gettime(CLOCK_TAI, &ts);
  timespec rt{};
  clock_gettime(CLOCK_REALTIME, &rt);
  TaiNs tai = static_cast<TaiNs>(ts.tv_sec) * kNsPerSecond + ts.tv_nsec;
  const TaiNs utc = static_cast<TaiNs>(rt.tv_sec) * kNsPerSecond + rt.tv_nsec;
  // CLOCK_TAI equals CLOCK_REALTIME while the kernel's TAI offset is unset (0).
  if (tai - utc < kNsPerSecond) tai = utc + kTaiMinusUtcSeconds * kNsPerSecond;
  return tai;
}

}  // namespace storetrack::time
