// storetrack-smooth-bench: is the fixed-interval smoother (host/smooth smooth_trajectory) linear
// in the number of samples? (issue 26, docs/performance.md "Smoother linearity".) One iteration
// smooths one tracked segment of N exposures at 400 fps; the time per sample is compared across
// N = 250 .. 16000. The per-exposure inputs are real: the processor's solutions of the
// store-separation scenario (4 cameras, 23 marks; simulated once), whose noise covariances and
// shared (calibration + survey) loadings are reused in turn along a longer synthetic trajectory
// of constant acceleration and angular acceleration (the smoother's own model: no step to
// detect), each pose drawn about it from its exposure's noise covariance.
#include <cmath>
#include <random>
#include <vector>

#include <benchmark/benchmark.h>
#include <Eigen/Cholesky>

#include "simulated_exposures.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/smooth/pose_smoother.hpp"

namespace {

using namespace storetrack;

constexpr std::int64_t kPeriodNs = 2'500'000;  // 400 fps

// The processor's solved exposures of the scenario, as the smoother takes them.
const std::vector<smooth::PoseMeasurement>& solved_exposures() {
  static const std::vector<smooth::PoseMeasurement> out = [] {
    const bench::SimulatedExposures& d = bench::store_separation();
    pipeline::ExposureProcessor proc = bench::make_processor(d.sim);
    std::vector<smooth::PoseMeasurement> m;
    for (const pipeline::AlignedExposure& ex : d.exposures)
      if (smooth::PoseMeasurement s = smooth::measurement_from(proc.process(ex)); s.solved)
        m.push_back(std::move(s));
    return m;
  }();
  return out;
}

// N exposures along the model's trajectory, exposure k taking the noise covariance and shared
// loadings of solved exposure k mod (their count), its pose drawn from that covariance.
std::vector<smooth::PoseMeasurement> segment(int n) {
  const std::vector<smooth::PoseMeasurement>& real = solved_exposures();
  std::mt19937_64 rng(26);
  std::normal_distribution<double> gauss;
  std::vector<smooth::PoseMeasurement> out;
  out.reserve(static_cast<std::size_t>(n));
  const geometry::Vec3 v(0.3, 0.0, 1.5), a(0.0, 0.5, 9.0);        // [m/s], [m/s^2]
  const geometry::Vec3 w(0.05, 0.6, 0.02), alpha(0.0, 0.3, 0.0);  // [rad/s], [rad/s^2]
  for (int k = 0; k < n; ++k) {
    smooth::PoseMeasurement m = real[static_cast<std::size_t>(k) % real.size()];
    const double t = k * (kPeriodNs * 1e-9);
    geometry::Transform truth = geometry::Transform::Identity();
    truth.linear() = geometry::rotation_from_rotvec(w * t + 0.5 * alpha * t * t);
    truth.translation() = real.front().T_p_s.translation() + v * t + 0.5 * a * t * t;
    geometry::Vec6 z;
    for (int i = 0; i < 6; ++i)
      z(i) = gauss(rng);
    m.T_p_s = geometry::perturb_left(truth, Eigen::LLT<geometry::Mat6>(m.cov_noise).matrixL() * z);
    m.t_ns = real.front().t_ns + k * kPeriodNs;
    out.push_back(std::move(m));
  }
  return out;
}

void BM_SmoothSegment(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const std::vector<smooth::PoseMeasurement> in = segment(n);
  smooth::SmootherCounters counters;
  for (auto _ : state) {
    counters = {};
    std::vector<smooth::SmoothedState> out =
        smooth::smooth_trajectory(in, smooth::SmootherConfig{}, &counters);
    benchmark::DoNotOptimize(out.data());
  }
  if (counters.segments != 1 || counters.measurements != static_cast<std::uint64_t>(n))
    state.SkipWithError("not one segment of every exposure");
  state.SetItemsProcessed(state.iterations() * n);
  state.counters["shared_columns"] = static_cast<double>(in.front().shared.cols());
  state.counters["steps"] = static_cast<double>(counters.steps);
}
BENCHMARK(BM_SmoothSegment)
    ->Arg(250)
    ->Arg(1000)
    ->Arg(4000)
    ->Arg(16000)
    ->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
