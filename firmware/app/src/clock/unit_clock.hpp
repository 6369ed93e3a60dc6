// UnitClock: the unit's idea of time. Its clock state (configured, the scenario's, or ptp4l's
// as read by clock::ClockMonitor) and TAI from the monotonic clock: a fixed offset when the
// source keeps a clock of its own (sim, replay), else the system's, refreshed with each health
// report. Exposure starts are stamped here, with their time uncertainty: the clock's (measured
// from ptp4l, or configured) combined with the trigger latch and sensor start jitter.
#pragma once

#include <cstdint>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>

#include "input/camera.hpp"
#include "storetrack/clock/clock_monitor.hpp"
#include "storetrack/frame/frame_source.hpp"
#include "storetrack/health/unit_state.hpp"
#include "unit_config.hpp"

namespace storetrack::unit {

class UnitClock {
 public:
  /// The configured state ("locking", "locked", "holdover", else free-running), or
  /// `scenario_state` when the camera brings one (sim, clock_state "auto").
  void configure(const std::string& clock_state, std::optional<std::uint8_t> scenario_state);
  /// The time uncertainty's parts: the configured jitters, and a configured clock's sigma (auto:
  /// `scenario_clock_sigma_ns` when the camera brings one, else unbounded if free-running, else
  /// 0). After configure().
  void configure_time(const TimeUncertaintyConfig& time,
                      std::optional<double> scenario_clock_sigma_ns, double holdover_drift_ppb);
  /// TAI - monotonic: the source's fixed offset when it keeps one, else the system's now.
  void follow_source(std::optional<std::int64_t> fixed_tai_minus_mono_ns);
  /// clock_state ptp4l: starts the monitor, polling at the health period. Returns false with
  /// `error` when its client cannot start.
  bool start_monitor(const UnitConfig& config, std::string& error);
  void stop();

  /// The state now: the monitor's (one relaxed load) or the configured.
  std::uint8_t state() const {
    return monitor_ ? static_cast<std::uint8_t>(monitor_->state()) : state_;
  }
  /// The state as of the last publish() (what the health report carries).
  std::uint8_t published_state() const { return state_; }
  /// Publishes the state and ptp4l's offset to the shared counters (Modbus, health).
  void publish(health::UnitCounters& counters);
  /// Before a health report: the system's TAI offset again (a source's fixed offset stays).
  void refresh_offset();
  std::int64_t tai_minus_mono_ns() const { return tai_minus_mono_ns_; }
  /// The exposure start in TAI: as the source recorded it (replay), else from the monotonic
  /// start through the offset, with the simulated clock's injected steps.
  std::int64_t exposure_start_tai_ns(const Camera& camera, const frame::FrameView& frame,
                                     time::MonotonicNs start_mono_ns) const;
  /// MarkObservations.exposure_time_sigma_ns of an exposure at `mono_ns` (the unit's live
  /// monotonic clock): the clock's uncertainty then (ptp4l: ClockFigure, grown in holdover; never
  /// measured: saturated)
  /// (+) latch (+) sensor jitter, in ns, saturated at 0xFFFFFFFE. No allocation, no system call.
  std::uint32_t exposure_time_sigma_ns(time::MonotonicNs mono_ns) const;
  /// The "clock" block of the stats.
  void add_stats(nlohmann::json& stats, const std::string& clock_state,
                 std::int32_t ptp_offset_ns) const;

 private:
  std::uint8_t state_ = 0;
  std::unique_ptr<clock::ClockMonitor> monitor_;  // clock_state ptp4l
  std::int64_t tai_minus_mono_ns_ = 0;
  bool fixed_offset_ = false;             // sim, replay: set at setup
  double configured_clock_sigma_ns_ = 0;  // without the monitor
  double jitter_ns_ = 0;                  // latch (+) sensor start
  double drift_ppb_ = 0;
};

}  // namespace storetrack::unit
