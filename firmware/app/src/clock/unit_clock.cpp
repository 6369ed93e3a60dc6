#include "clock/unit_clock.hpp"

#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>

namespace storetrack::unit {
namespace {

std::uint8_t parse_clock_state(const std::string& s) {
  if (s == "locking") return static_cast<std::uint8_t>(time::ClockState::kLocking);
  if (s == "locked") return static_cast<std::uint8_t>(time::ClockState::kLocked);
  if (s == "holdover") return static_cast<std::uint8_t>(time::ClockState::kHoldover);
  return static_cast<std::uint8_t>(time::ClockState::kFreeRunning);
}

}  // namespace

void UnitClock::configure(const std::string& clock_state,
                          std::optional<std::uint8_t> scenario_state) {
  state_ = scenario_state ? *scenario_state : parse_clock_state(clock_state);
}

void UnitClock::configure_time(const TimeUncertaintyConfig& time,
                               std::optional<double> scenario_clock_sigma_ns,
                               double holdover_drift_ppb) {
  // auto without a scenario: a free-running clock was never compared with a master.
  const bool free_running = state_ == static_cast<std::uint8_t>(time::ClockState::kFreeRunning);
  const double auto_ns = scenario_clock_sigma_ns ? *scenario_clock_sigma_ns
                         : free_running          ? std::numeric_limits<double>::infinity()
                                                 : 0.0;
  configured_clock_sigma_ns_ = time.clock_sigma_ns >= 0 ? time.clock_sigma_ns : auto_ns;
  jitter_ns_ = std::hypot(time.latch_jitter_ns, time.sensor_start_jitter_ns);
  drift_ppb_ = holdover_drift_ppb;
}

std::uint32_t UnitClock::exposure_time_sigma_ns(time::MonotonicNs mono_ns) const {
  const double clock_ns =
      monitor_ ? monitor_->figure().sigma_ns_at(mono_ns, drift_ppb_) : configured_clock_sigma_ns_;
  const double sigma_ns = std::hypot(clock_ns, jitter_ns_);  // +inf stays +inf
  constexpr double kSaturated = 4294967294.0;                // 0xFFFFFFFE: >= 4.29 s
  return sigma_ns < kSaturated ? static_cast<std::uint32_t>(std::lround(sigma_ns))
                               : static_cast<std::uint32_t>(kSaturated);
}

void UnitClock::follow_source(std::optional<std::int64_t> fixed_tai_minus_mono_ns) {
  fixed_offset_ = fixed_tai_minus_mono_ns.has_value();
  tai_minus_mono_ns_ =
      fixed_offset_ ? *fixed_tai_minus_mono_ns : time::tai_now_ns() - time::monotonic_now_ns();
}

bool UnitClock::start_monitor(const UnitConfig& config, std::string& error) {
  if (config.clock_state != "ptp4l") return true;
  clock::ClockMonitorConfig cc = config.ptp4l;
  cc.poll_period_ms = config.health_period_ms;
  monitor_ = std::make_unique<clock::ClockMonitor>(cc);
  if (monitor_->start() < 0) {
    error = "clock: ptp4l client: " + monitor_->error();
    return false;
  }
  return true;
}

void UnitClock::stop() {
  if (monitor_) monitor_->stop();
}

void UnitClock::publish(health::UnitCounters& counters) {
  state_ = state();
  counters.clock_state.store(state_, std::memory_order_relaxed);
  if (monitor_) counters.ptp_offset_ns.store(monitor_->offset_ns(), std::memory_order_relaxed);
}

void UnitClock::refresh_offset() {
  if (!fixed_offset_) tai_minus_mono_ns_ = time::tai_now_ns() - time::monotonic_now_ns();
}

std::int64_t UnitClock::exposure_start_tai_ns(const Camera& camera, const frame::FrameView& frame,
                                              time::MonotonicNs start_mono_ns) const {
  if (const auto recorded = camera.recorded_tai_ns())
    return *recorded + (start_mono_ns - frame.timestamp_mono_ns);
  return start_mono_ns + tai_minus_mono_ns_ + camera.tai_step_ns(frame.sequence);
}

void UnitClock::add_stats(nlohmann::json& stats, const std::string& clock_state,
                          std::int32_t ptp_offset_ns) const {
  stats["clock"] = {
      {"source", clock_state == "ptp4l" ? "ptp4l" : "configured"},
      {"state", static_cast<int>(state())},
      {"ptp_offset_ns", ptp_offset_ns},
      {"exposure_time_sigma_ns_now", exposure_time_sigma_ns(time::monotonic_now_ns())}};
  if (!monitor_) return;
  const clock::ClockMonitorStats cs = monitor_->stats();
  stats["clock"]["ptp4l"] = {{"polls", cs.polls},
                             {"answered_polls", cs.answered_polls},
                             {"transitions", cs.transitions},
                             {"port_state", clock::to_string(cs.port_state)},
                             {"gm_present", cs.gm_present},
                             {"time_traceable", cs.time_traceable},
                             {"master_offset_ns", cs.master_offset_ns},
                             {"new_offsets", cs.new_offsets},
                             {"offset_rms_ns", cs.offset_rms_ns},
                             {"requests", cs.client.requests},
                             {"replies", cs.client.replies},
                             {"timeouts", cs.client.timeouts},
                             {"send_errors", cs.client.send_errors},
                             {"malformed", cs.client.malformed},
                             {"stale", cs.client.stale},
                             {"error_status", cs.client.error_status},
                             {"last_errno", cs.client.last_errno}};
}

}  // namespace storetrack::unit
