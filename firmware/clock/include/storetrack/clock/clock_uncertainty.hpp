// The unit clock's standard uncertainty against its PTP master, from what ptp4l measured
// (docs/reliability.md, "Clock: time uncertainty"):
//
//   holding     tracking the master with a fresh measurement (LOCKED, LOCKING): u = the RMS of
//               the last `offset_window` new master offsets. ptp4l's master offset is the
//               clock's error left by its servo; their RMS, bias included, is a Type A estimate
//               of that error (JCGM 100:2008, 4.2).
//   not holding after a measurement (HOLDOVER, FREE_RUNNING once the master is lost): the clock
//               runs on its oscillator, steered by the last frequency the servo set. Its phase
//               error then grows at most linearly with the oscillator's fractional frequency
//               stability y: u(t) = sqrt(u_last^2 + (y (t - t_last))^2), t_last the last new
//               measurement (IEEE 1588-2019 Annex on holdover; ITU-T G.8273.2 bounds it the
//               same way).
//   never measured: unbounded (the system clock was never compared with a master).
//
// Allocation-free: the window is fixed storage; the capture loop only evaluates a ClockFigure.
#pragma once

#include <array>
#include <cstdint>

#include "storetrack/time/time.hpp"

namespace storetrack::clock {

struct ClockUncertaintyConfig {
  int offset_window = 16;            ///< new offsets in the RMS, 1..kMaxOffsetWindow
  double holdover_drift_ppb = 1000;  ///< oscillator stability bound y once unsteered [1e-9]
};

inline constexpr int kMaxOffsetWindow = 64;

/// The clock's figure as of its last poll: enough to state its uncertainty at any later time.
struct ClockFigure {
  double rms_ns = 0;                     ///< RMS of the window at measured_at_ns
  time::MonotonicNs measured_at_ns = 0;  ///< the last new offset (monotonic); 0: never measured
  bool holding = false;                  ///< tracking with a fresh measurement: no growth

  /// u at `t_ns` (monotonic) with stability `drift_ppb`; +infinity if never measured.
  double sigma_ns_at(time::MonotonicNs t_ns, double drift_ppb) const;
};

/// The RMS of the last `size` offsets, in fixed storage.
class OffsetWindow {
 public:
  explicit OffsetWindow(int size);
  void add(std::int64_t offset_ns);
  double rms_ns() const;
  int count() const { return count_; }

 private:
  std::array<double, kMaxOffsetWindow> squares_{};
  int size_;
  int next_ = 0;
  int count_ = 0;
};

}  // namespace storetrack::clock
