// TriggerLine: the exposure trigger of a camera unit.
//
// Master mode: the unit drives the trigger output line(s) itself and reports each pulse it
// generated. Slave mode: the unit follows an external trigger (FTI system or another unit) and
// reports each rising edge with the kernel's time stamp. Either way the capture loop drains the
// edges with read_edges() and pairs them with frames (frame_pairer.hpp).
//
// All calls return 0 / a count on success or a negative errno value; none allocate or throw
// after start().
#pragma once

#include <cstdint>
#include <span>

#include "storetrack/time/time.hpp"

namespace storetrack::trigger {

/// One trigger edge as seen (slave) or generated (master) by the unit.
struct TriggerEdge {
  time::MonotonicNs t_mono_ns = 0;  ///< rising edge, unit CLOCK_MONOTONIC
  std::uint32_t line_count = 0;     ///< the line's own running edge counter (0, 1, 2, ...)
};

/// Counters of the line itself (the pairer counts the pairing statistics).
struct TriggerLineStats {
  std::uint64_t edges = 0;          ///< edges generated (master) or received (slave)
  std::uint64_t overruns = 0;       ///< master: pulses skipped because the thread woke later
                                    ///< than max_late_ns (gpio_trigger.hpp);
                                    ///< slave: edge events lost in the kernel queue
  std::int64_t max_late_ns = 0;     ///< master: worst wake-up lateness against the schedule
  std::uint64_t dropped_edges = 0;  ///< edges lost because the reader did not drain in time
  /// master: a line could not be set (that pulse is lost, the others keep their place on the
  /// grid; the lines are requested again after kLineErrorsBeforeReopen in a row); slave:
  /// waiting for or reading edge events failed.
  std::uint64_t line_errors = 0;
  std::uint64_t reopens = 0;  ///< lines requested again after errors
};

/// Consecutive line errors after which a trigger line is released and requested again (a GPIO
/// chip that went away and came back: its old line handles stay dead).
inline constexpr int kLineErrorsBeforeReopen = 10;

class TriggerLine {
 public:
  virtual ~TriggerLine() = default;
  /// Requests the lines; master mode starts generating pulses.
  virtual int start() = 0;
  virtual int stop() = 0;
  /// Waits up to timeout_ms (0: do not wait) for edges and moves up to out.size() of them
  /// into `out`, oldest first. Returns the number of edges or -errno.
  virtual int read_edges(std::span<TriggerEdge> out, int timeout_ms) = 0;
  virtual bool is_master() const = 0;
  virtual TriggerLineStats stats() const = 0;
  /// Identity for error messages ("gpiochip0 line 3 (slave)", "sim trigger").
  virtual const char* name() const = 0;
};

}  // namespace storetrack::trigger
