// The unit's clock state (time::ClockState, the wire enum: 0 free-running, 1 locking, 2 locked,
// 3 holdover) from what ptp4l reports, one poll at a time (docs/reliability.md, "Clock"):
//
//   tracking  = ptp4l answered, a grandmaster other than this clock is present (gmPresent), the
//               port is SLAVE or UNCALIBRATED, and, if required, the time is traceable
//   servo ok  = port SLAVE (ptp4l's servo locked); with measure_only also UNCALIBRATED, because a
//               ptp4l with `free_running 1` never steers its clock, so never leaves UNCALIBRATED
//   measured  = ptp4l has a measurement (ingress_time != 0: before its first Sync, ptp4l
//               reports offset 0) that is fresh (ingress_time changed within offset_max_age_ns:
//               a master that still announces but no longer sends Sync leaves it unchanged)
//   within    = tracking, servo ok, measured and |master offset| <= lock_threshold_ns
//
//   LOCKED        after lock_polls consecutive polls within; left on the first poll not within
//   LOCKING       tracking but not (yet) LOCKED
//   HOLDOVER      was LOCKED and the grandmaster is gone (not tracking: port not SLAVE, no
//                 gmPresent, or ptp4l not answering), for at most holdover_ns
//   FREE_RUNNING  otherwise: never locked, lost while LOCKING, or holdover expired
//
// Allocation-free, no system calls: the caller supplies the poll's time.
#pragma once

#include <cstdint>

#include "storetrack/clock/ptp_management.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::clock {

struct LockThresholds {
  std::int64_t lock_threshold_ns = 1000;  ///< |offset from master| for LOCKED (HW stamping: < 100)
  int lock_polls = 3;                     ///< consecutive polls within before LOCKED
  std::int64_t holdover_ns = 10'000'000'000;  ///< HOLDOVER lasts at most this long (0: none)
  bool measure_only = false;            ///< ptp4l runs free_running: UNCALIBRATED is a measurement
  bool require_time_traceable = false;  ///< LOCKED only to a grandmaster with timeTraceable
  /// An offset whose Sync (ingress_time) has not changed for this long is stale, not within.
  std::int64_t offset_max_age_ns = 5'000'000'000;
};

/// One poll of ptp4l, as the state machine needs it.
struct PtpPoll {
  bool answered = false;  ///< PORT_DATA_SET and TIME_STATUS_NP both replied
  PortState port_state = PortState::kUnknown;
  bool gm_present = false;
  std::int64_t master_offset_ns = 0;
  std::int64_t ingress_time_ns = 0;  ///< of the Sync behind master_offset_ns; 0: none yet
  bool time_traceable = false;       ///< TIME_PROPERTIES_DATA_SET timeTraceable (false if unknown)
};

/// INT32_MIN is "unknown" on the wire (UnitHealth, Modbus): known offsets saturate one above it.
inline constexpr std::int32_t kOffsetUnknown = INT32_MIN;
std::int32_t saturate_offset_ns(std::int64_t offset_ns);

class LockStateMachine {
 public:
  explicit LockStateMachine(LockThresholds thresholds) : thresholds_(thresholds) {}

  /// Advances by one poll taken at `now_ns` (monotonic); returns the new state.
  time::ClockState update(const PtpPoll& poll, time::MonotonicNs now_ns);

  time::ClockState state() const { return state_; }
  /// The poll's offset from the master while tracking, else kOffsetUnknown.
  std::int32_t offset_ns() const { return offset_ns_; }
  /// The last poll, tracking, brought a new measurement (a Sync not seen before).
  bool new_measurement() const { return new_measurement_; }
  /// The last poll was tracking with a fresh measurement: the clock follows its master.
  bool holding() const { return holding_; }
  const LockThresholds& thresholds() const { return thresholds_; }

 private:
  bool tracking(const PtpPoll& poll) const;
  bool servo_ok(const PtpPoll& poll) const;
  bool measured(const PtpPoll& poll, time::MonotonicNs now_ns);
  time::ClockState on_master_lost(time::MonotonicNs now_ns);

  LockThresholds thresholds_;
  time::ClockState state_ = time::ClockState::kFreeRunning;
  std::int32_t offset_ns_ = kOffsetUnknown;
  int consecutive_within_ = 0;
  time::MonotonicNs holdover_since_ns_ = 0;
  std::int64_t last_ingress_time_ns_ = 0;
  time::MonotonicNs ingress_changed_ns_ = 0;  ///< when ingress_time last changed
  bool ingress_new_ = false;                  ///< ingress_time changed in this poll
  bool new_measurement_ = false;
  bool holding_ = false;
};

}  // namespace storetrack::clock
