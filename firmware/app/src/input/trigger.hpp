// Trigger: the unit's trigger line together with what the capture loop asks of its kind.
// A simulated trigger makes its edges from the frames' own times (each frame moves it on); a
// gpio master generates the rig's pulses and is restarted for a new rate or pulse width.
// input_factory.cpp is the one place that knows the kinds.
#pragma once

#include <cstdint>
#include <memory>

#include "storetrack/time/time.hpp"
#include "storetrack/trigger/trigger_line.hpp"

namespace storetrack::unit {

/// What became of a new trigger rate or pulse width (Modbus trigger_rate_hz, pulse_width_us).
enum class TriggerChange {
  kApplied,             ///< running with it (or nothing to restart: the pairing follows it)
  kInvalid,             ///< refused before anything stopped
  kKeptPrevious,        ///< the new one did not start; the previous one runs again
  kPreviousNotRunning,  ///< ... and the previous one did not start again: retried
};

/// A stopped generator's retry (retry_stopped()).
enum class TriggerRetry {
  kNothingToDo,  ///< running, or not yet time to try again
  kStillDown,    ///< tried, did not start
  kRunning,      ///< running again
};

class Trigger {
 public:
  explicit Trigger(std::unique_ptr<trigger::TriggerLine> line);
  virtual ~Trigger();
  Trigger(const Trigger&) = delete;
  Trigger& operator=(const Trigger&) = delete;

  trigger::TriggerLine& line() { return *line_; }
  const trigger::TriggerLine& line() const { return *line_; }

  /// True when the edges come from the frames (sim): nothing to read while waiting for one.
  virtual bool follows_frames() const { return false; }
  /// follows_frames(): the first frame's edge sets the trigger's phase ...
  virtual void set_origin(time::MonotonicNs /*edge_ns*/) {}
  /// ... and each frame lets it fire up to the end of its pairing window.
  virtual void advance_to(time::MonotonicNs /*t_ns*/) {}
  /// A new rate or pulse width for a trigger that generates the pulses itself (gpio master).
  virtual TriggerChange change(double /*rate_hz*/, std::int64_t /*width_ns*/) {
    return TriggerChange::kApplied;
  }
  /// A generator not started again after a failed change (kPreviousNotRunning): nothing drives
  /// the rig's trigger, so it is tried again once a second until it runs.
  virtual TriggerRetry retry_stopped() { return TriggerRetry::kNothingToDo; }
  /// Pulses the trigger could not drive since the last call (a gpio master's own thread counts
  /// them; a reader's line errors are its failed reads, counted by the pairing).
  virtual std::uint64_t new_pulse_errors() { return 0; }

 protected:
  std::unique_ptr<trigger::TriggerLine> line_;
};

}  // namespace storetrack::unit
