#include "storetrack/clearance/sample_clearance.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <utility>

namespace storetrack::clearance {

SampleClearance::SampleClearance(ClearanceModel model, double alarm_threshold_m)
    : model_(std::move(model)), alarm_threshold_m_(alarm_threshold_m) {
  if (!std::isfinite(alarm_threshold_m_))
    throw std::invalid_argument("clearance.alarm_threshold_m must be a finite number of metres");
  if (model_.aircraft_parts() == 0 ||
      model_.aircraft_parts() >= msg::fti_sample_invalid::kClearancePart)
    throw std::invalid_argument("clearance geometry: needs 1 to 65534 aircraft parts");
  parts_.reserve(model_.aircraft_parts());
}

void SampleClearance::clear(msg::FtiSample& sample) {
  sample.clearance_m = msg::fti_sample_invalid::kClearanceM;
  sample.u_clearance_m = msg::fti_sample_invalid::kUClearanceM;
  sample.clearance_lower_bound_m = msg::fti_sample_invalid::kClearanceLowerBoundM;
  sample.clearance_part = msg::fti_sample_invalid::kClearancePart;
}

void SampleClearance::apply(const geometry::Transform& T_p_s, const geometry::Mat6& cov_T_p_s,
                            msg::FtiSample& sample) {
  model_.evaluate(T_p_s, cov_T_p_s, parts_);
  ++counters_.samples_evaluated;
  // The part the store is surely nearest to: the lowest lower bound (a NaN bound, from a
  // covariance that is not finite, is never chosen over a number).
  std::size_t lowest = 0;
  for (std::size_t i = 1; i < parts_.size(); ++i)
    if (parts_[i].lower_bound_m < parts_[lowest].lower_bound_m ||
        std::isnan(parts_[lowest].lower_bound_m))
      lowest = i;
  const PartClearance& c = parts_[lowest];
  sample.clearance_m = static_cast<float>(c.distance_m);
  sample.u_clearance_m = static_cast<float>(c.u_distance_m);
  sample.clearance_lower_bound_m = static_cast<float>(c.lower_bound_m);
  sample.clearance_part = static_cast<std::uint16_t>(lowest);
  // A bound that is not a number cannot clear the threshold: it alarms.
  const bool alarm = !(c.lower_bound_m >= alarm_threshold_m_);
  alarm_changed_ = alarm != alarm_;
  alarm_ = alarm;
  if (alarm) {
    sample.status |= msg::fti_status::kClearanceAlarm;
    ++counters_.alarm_samples;
    if (alarm_changed_) ++counters_.alarm_episodes;
  }
}

}  // namespace storetrack::clearance
