// The clearance of each sample (docs/clearance.md, "In the host"): the store posed by the
// sample's T_p_s and its covariance against every aircraft part of the geometry; the part with
// the lowest k = 2 lower bound goes into the FtiSample (clearance_m, u_clearance_m,
// clearance_lower_bound_m, clearance_part) and the status bit clearance_alarm is set when that
// bound is below the alarm threshold.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "storetrack/clearance/clearance.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/msg/messages.hpp"

namespace storetrack::clearance {

struct ClearanceCounters {
  std::uint64_t samples_evaluated = 0;  ///< samples with a pose whose clearance was computed
  std::uint64_t alarm_samples = 0;      ///< of them, with status bit clearance_alarm
  std::uint64_t alarm_episodes = 0;     ///< runs of consecutive alarm samples (alarm starts)
};

class SampleClearance {
 public:
  /// `alarm_threshold_m`: metres, on the k = 2 lower bound (finite; may be negative).
  SampleClearance(ClearanceModel model, double alarm_threshold_m);

  /// Evaluates the store posed by T_p_s (cov over its left perturbation) and writes the
  /// sample's clearance fields and status bit clearance_alarm. Allocation-free once warm.
  void apply(const geometry::Transform& T_p_s, const geometry::Mat6& cov_T_p_s,
             msg::FtiSample& sample);
  /// A sample without a pose: its clearance fields stay invalid, the alarm state is kept.
  static void clear(msg::FtiSample& sample);

  /// Every part's clearance of the last apply() (file order of the aircraft parts).
  const std::vector<PartClearance>& parts() const { return parts_; }
  const ClearanceModel& model() const { return model_; }
  double alarm_threshold_m() const { return alarm_threshold_m_; }
  /// The last evaluated sample was in alarm; alarm_changed(): it started or ended there.
  bool alarm() const { return alarm_; }
  bool alarm_changed() const { return alarm_changed_; }
  const ClearanceCounters& counters() const { return counters_; }

 private:
  ClearanceModel model_;
  double alarm_threshold_m_;
  std::vector<PartClearance> parts_;
  bool alarm_ = false, alarm_changed_ = false;
  ClearanceCounters counters_;
};

}  // namespace storetrack::clearance
