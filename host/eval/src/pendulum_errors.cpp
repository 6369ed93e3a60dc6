// SisTrO's dynamic table from the per-sample errors (measured - reference): per world axis the
// mean and standard deviation (the dynamic uncertainty, 1 sigma), per direction of swing, the
// model's own error (clockwise minus counter-clockwise mean), and the error binned by distance
// from the optical axis and by mark speed (equal-count bins).
#include <algorithm>
#include <cmath>
#include <limits>

#include "pendulum_internal.hpp"

namespace storetrack::eval::detail {
namespace {

template <typename Keep>
std::array<DynamicAxis, 3> axis_statistics(const std::vector<SampleError>& samples, Keep keep,
                                           int& count) {
  std::array<DynamicAxis, 3> out{};
  count = 0;
  std::array<double, 3> sum{}, sum_sq{}, ref_sq{}, stated_sq{};
  for (const SampleError& s : samples) {
    if (!keep(s)) continue;
    ++count;
    for (size_t k = 0; k < 3; ++k) {
      const auto i = static_cast<Eigen::Index>(k);
      sum[k] += s.error_m(i);
      ref_sq[k] += s.u_reference_m(i) * s.u_reference_m(i);
      stated_sq[k] += s.u_stated_m(i) * s.u_stated_m(i);
    }
  }
  if (count == 0) return out;
  for (size_t k = 0; k < 3; ++k)
    out[k].mean_m = sum[k] / count;
  for (const SampleError& s : samples) {
    if (!keep(s)) continue;
    for (size_t k = 0; k < 3; ++k) {
      const double d = s.error_m(static_cast<Eigen::Index>(k)) - out[k].mean_m;
      sum_sq[k] += d * d;
    }
  }
  for (size_t k = 0; k < 3; ++k) {
    out[k].sd_m = count > 1 ? std::sqrt(sum_sq[k] / (count - 1)) : 0;
    out[k].u_reference_m = std::sqrt(ref_sq[k] / count);
    out[k].u_stated_m = std::sqrt(stated_sq[k] / count);
  }
  return out;
}

template <typename Key>
std::vector<DynamicBin> equal_count_bins(const std::vector<SampleError>& samples, int bins,
                                         Key key) {
  std::vector<const SampleError*> sorted;
  for (const SampleError& s : samples)
    sorted.push_back(&s);
  std::sort(sorted.begin(), sorted.end(),
            [&](const SampleError* a, const SampleError* b) { return key(*a) < key(*b); });
  std::vector<DynamicBin> out;
  const size_t n = sorted.size();
  for (int b = 0; b < bins && n > 0; ++b) {
    const size_t lo = n * static_cast<size_t>(b) / static_cast<size_t>(bins);
    const size_t hi = n * static_cast<size_t>(b + 1) / static_cast<size_t>(bins);
    if (hi <= lo) continue;
    DynamicBin bin;
    bin.low = key(*sorted[lo]);
    bin.high = key(*sorted[hi - 1]);
    bin.samples = static_cast<int>(hi - lo);
    for (size_t i = lo; i < hi; ++i)
      for (size_t k = 0; k < 3; ++k) {
        const double e = sorted[i]->error_m(static_cast<Eigen::Index>(k));
        bin.rms_m[k] += e * e;
      }
    for (double& v : bin.rms_m)
      v = std::sqrt(v / bin.samples);
    out.push_back(bin);
  }
  return out;
}

}  // namespace

void summarise_dynamic_errors(const std::vector<SampleError>& samples, PendulumResult& result) {
  int all = 0;
  result.dynamic = axis_statistics(
      samples, [](const SampleError&) { return true; }, all);
  result.dynamic_clockwise = axis_statistics(
      samples, [](const SampleError& s) { return s.clockwise; }, result.samples_clockwise);
  result.dynamic_counter_clockwise = axis_statistics(
      samples, [](const SampleError& s) { return !s.clockwise; }, result.samples_counter_clockwise);
  const bool both = result.samples_clockwise > 1 && result.samples_counter_clockwise > 1;
  for (size_t k = 0; k < 3; ++k) {
    const DynamicAxis &cw = result.dynamic_clockwise[k], &ccw = result.dynamic_counter_clockwise[k];
    result.model_error_m[k] =
        both ? cw.mean_m - ccw.mean_m : std::numeric_limits<double>::quiet_NaN();
    result.model_error_u_m[k] =
        both ? std::hypot(cw.sd_m, ccw.sd_m) : std::numeric_limits<double>::quiet_NaN();
  }
  const PendulumOptions& o = result.options;
  if (o.T_w_camera)
    result.by_axis_distance = equal_count_bins(
        samples, o.distance_bins, [](const SampleError& s) { return s.axis_distance_m; });
  result.by_speed =
      equal_count_bins(samples, o.speed_bins, [](const SampleError& s) { return s.speed_m_s; });
}

}  // namespace storetrack::eval::detail
