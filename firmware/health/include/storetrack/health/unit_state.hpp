// State shared between the capture loop (writer) and the health server / UnitHealth reporter
// (readers): relaxed atomics only, no locks, so the capture loop never waits on the server.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <span>
#include <string>

#include "storetrack/health/register_map.hpp"

namespace storetrack::health {

struct UnitCounters {
  std::atomic<std::uint64_t> frames_captured{0};
  std::atomic<std::uint64_t> frames_dropped{0};
  std::atomic<std::uint64_t> triggers_seen{0};
  std::atomic<std::uint64_t> triggers_missing{0};
  std::atomic<std::uint64_t> triggers_extra{0};
  std::atomic<std::uint64_t> observations_sent{0};
  std::atomic<std::uint64_t> link_tx_errors{0};
  std::atomic<std::uint64_t> link_tx_dropped{0};
  std::atomic<std::uint64_t> can_bus_off_count{0};
  std::atomic<std::uint64_t> can_error_frames{0};
  std::atomic<std::uint64_t> centroid_errors{0};       ///< frames the centroider refused
  std::atomic<std::uint32_t> centroid_time_us_max{0};  ///< over the current health period
  std::atomic<std::uint32_t> marks_last_frame{0};
  std::atomic<std::uint16_t> status{0};  ///< msg::unit_status bits
  std::atomic<std::uint8_t> clock_state{0};
  std::atomic<std::int32_t> ptp_offset_ns{INT32_MIN};
  std::atomic<std::int16_t> sensor_temp_cdeg{INT16_MIN};
  std::atomic<std::int16_t> board_temp_cdeg{INT16_MIN};

  static void add(std::atomic<std::uint64_t>& c, std::uint64_t n = 1) {
    c.fetch_add(n, std::memory_order_relaxed);
  }
  static void max(std::atomic<std::uint32_t>& c, std::uint32_t v) {
    std::uint32_t cur = c.load(std::memory_order_relaxed);
    while (v > cur && !c.compare_exchange_weak(cur, v, std::memory_order_relaxed)) {
    }
  }
};

inline constexpr std::size_t kHoldingCount = static_cast<std::size_t>(HoldingField::kCount);

/// The holding-register configuration. Written by the Modbus server (maintenance mode) or at
/// start from the config file; the capture loop polls generation() and takes a snapshot() on
/// change. Invariant: a write is validated whole (its cross-register rules against the values
/// it leaves) and seen whole: snapshot() never returns half of a multi-register write (a
/// sequence lock; one writer, the Modbus thread).
class ConfigStore {
 public:
  using Values = std::array<std::uint16_t, kHoldingCount>;  ///< indexed by HoldingField

  ConfigStore();
  /// A consistent copy of every value.
  Values snapshot() const;
  /// From now on a write that changes unit_id or camera_id is refused with -EBUSY: the unit's
  /// identity changes only when it restarts with it in its configuration (the host would apply
  /// another camera's calibration to a renamed one mid-run).
  void lock_identity() { identity_locked_.store(true, std::memory_order_relaxed); }
  /// A search region written must fit this frame.
  void set_limits(const HoldingLimits& limits) { limits_ = limits; }
  std::uint16_t get(HoldingField f) const {
    return values_[static_cast<std::size_t>(f)].load(std::memory_order_relaxed);
  }
  /// Sets without validation (start-up from the config file, which validates itself).
  void set(HoldingField f, std::uint16_t v) {
    values_[static_cast<std::size_t>(f)].store(v, std::memory_order_relaxed);
  }
  /// Copies the values in address order.
  void read_all(std::span<std::uint16_t> out) const;
  /// Validated write from the Modbus server: 0, -EFAULT or -EINVAL (see
  /// validate_holding_write), -EBUSY for an identity change once locked; on success bumps the
  /// generation.
  int write(std::uint16_t address, std::span<const std::uint16_t> values, std::string* why);
  std::uint32_t generation() const { return generation_.load(std::memory_order_acquire); }

 private:
  std::array<std::atomic<std::uint16_t>, kHoldingCount> values_{};
  std::atomic<std::uint32_t> generation_{0};
  std::atomic<std::uint32_t> sequence_{0};  // odd while a write is being stored
  std::atomic<bool> identity_locked_{false};
  HoldingLimits limits_;  // set before the Modbus thread starts
};

/// Fills the input registers (address order of the table) from the counters.
void fill_input_registers(const UnitCounters& c, std::uint32_t uptime_s,
                          std::uint32_t config_generation, std::span<std::uint16_t> regs);

/// Board temperature in 0.01 degC from /sys/class/thermal/thermal_zone*/temp (the hottest
/// zone), or INT16_MIN when there is none. `root` is for tests.
std::int16_t read_board_temp_cdeg(const std::string& root = "/sys/class/thermal");

inline constexpr std::uint16_t kFirmwareVersion = 0x0001;  ///< 0.1

}  // namespace storetrack::health
