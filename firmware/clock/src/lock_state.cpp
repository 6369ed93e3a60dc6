#include "storetrack/clock/lock_state.hpp"

#include <cstdlib>

namespace storetrack::clock {

std::int32_t saturate_offset_ns(std::int64_t offset_ns) {
  if (offset_ns > INT32_MAX) return INT32_MAX;
  if (offset_ns <= INT32_MIN) return INT32_MIN + 1;
  return static_cast<std::int32_t>(offset_ns);
}

bool LockStateMachine::tracking(const PtpPoll& poll) const {
  const bool port_follows_master =
      poll.port_state == PortState::kSlave || poll.port_state == PortState::kUncalibrated;
  return poll.answered && poll.gm_present && port_follows_master &&
         (!thresholds_.require_time_traceable || poll.time_traceable);
}

bool LockStateMachine::servo_ok(const PtpPoll& poll) const {
  return poll.port_state == PortState::kSlave ||
         (thresholds_.measure_only && poll.port_state == PortState::kUncalibrated);
}

bool LockStateMachine::measured(const PtpPoll& poll, time::MonotonicNs now_ns) {
  ingress_new_ = poll.ingress_time_ns != last_ingress_time_ns_;
  if (ingress_new_) {
    last_ingress_time_ns_ = poll.ingress_time_ns;
    ingress_changed_ns_ = now_ns;
  }
  return poll.ingress_time_ns != 0 && now_ns - ingress_changed_ns_ < thresholds_.offset_max_age_ns;
}

time::ClockState LockStateMachine::on_master_lost(time::MonotonicNs now_ns) {
  using time::ClockState;
  switch (state_) {
    case ClockState::kLocked:
      if (thresholds_.holdover_ns <= 0) return ClockState::kFreeRunning;
      holdover_since_ns_ = now_ns;
      return ClockState::kHoldover;
    case ClockState::kHoldover:
      return now_ns - holdover_since_ns_ >= thresholds_.holdover_ns ? ClockState::kFreeRunning
                                                                    : ClockState::kHoldover;
    case ClockState::kLocking:
    case ClockState::kFreeRunning:
      break;
  }
  return ClockState::kFreeRunning;
}

time::ClockState LockStateMachine::update(const PtpPoll& poll, time::MonotonicNs now_ns) {
  using time::ClockState;
  if (!tracking(poll)) {
    measured(poll, now_ns);  // keeps the ingress_time history
    new_measurement_ = holding_ = false;
    consecutive_within_ = 0;
    offset_ns_ = kOffsetUnknown;
    state_ = on_master_lost(now_ns);
    return state_;
  }
  offset_ns_ = saturate_offset_ns(poll.master_offset_ns);
  // llabs of INT64_MIN is undefined: compare the two signs separately.
  const bool small = poll.master_offset_ns <= thresholds_.lock_threshold_ns &&
                     poll.master_offset_ns >= -thresholds_.lock_threshold_ns;
  const bool fresh = measured(poll, now_ns);
  holding_ = fresh;
  new_measurement_ = fresh && ingress_new_;
  if (fresh && servo_ok(poll) && small) {
    if (consecutive_within_ < thresholds_.lock_polls) ++consecutive_within_;
    state_ =
        consecutive_within_ >= thresholds_.lock_polls ? ClockState::kLocked : ClockState::kLocking;
  } else {
    consecutive_within_ = 0;
    state_ = ClockState::kLocking;
  }
  return state_;
}

}  // namespace storetrack::clock
