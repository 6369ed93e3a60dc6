// storetrack-host-bench: cost of one exposure on the host (4 cameras, 23 marks, store
// separation from the simulator's fast mode): identification alone, identification +
// geometry, geometry with known ids; and triangulation per point against OpenCV's
// linear cv::triangulatePoints on the same observations (docs/performance.md, "Host processing").
#include <string>
#include <vector>

#include <benchmark/benchmark.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "storetrack/match/mark_matcher.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/sim/simulator.hpp"
#include "storetrack/triangulate/triangulate.hpp"

namespace {

using namespace storetrack;

struct Data {
  Data()
      : sim(sim::load_scenario(std::string(STORETRACK_SCENARIO_DIR) + "/store_separation.json"),
            3) {
    for (int k = 0; k < sim.num_exposures(); ++k) {
      pipeline::AlignedExposure ex;
      pipeline::MarkIds ids(static_cast<size_t>(sim.num_cameras()));
      ex.cameras.resize(ids.size());
      for (int c = 0; c < sim.num_cameras(); ++c)
        sim.observe(k, c, ex.cameras[static_cast<size_t>(c)], &ids[static_cast<size_t>(c)]);
      ex.trigger_seq = ex.cameras[0].trigger_seq;
      exposures.push_back(ex);
      truth_ids.push_back(ids);
    }
  }
  sim::Simulator sim;
  std::vector<pipeline::AlignedExposure> exposures;
  std::vector<pipeline::MarkIds> truth_ids;
};

const Data& data() {
  static const Data d;
  return d;
}

pipeline::ExposureProcessor make_processor(const Data& d) {
  pipeline::ExposureProcessor proc(d.sim.calibrated_rig(), d.sim.pylon_survey(),
                                   d.sim.store_survey(), pipeline::ProcessorConfig{});
  geometry::Mat6 prior = geometry::Mat6::Identity() * 1e-4;
  proc.matcher().set_prior_pose("pylon", d.sim.scenario().T_w_p, prior);
  proc.matcher().set_prior_pose("store",
                                d.sim.scenario().T_w_p * d.sim.scenario().separation.T_p_s0, prior);
  return proc;
}

// Identification alone: MarkMatcher::match (the processor's own matcher, so the same priors and
// configuration), tracked exposure after exposure.
void BM_Match(benchmark::State& state) {
  const Data& d = data();
  auto proc = make_processor(d);
  match::MarkMatcher& matcher = proc.matcher();
  size_t k = 0, identified = 0;
  for (auto _ : state) {
    const match::MatchResult r = matcher.match(d.exposures[k].cameras);
    benchmark::DoNotOptimize(r.ids.data());
    identified += static_cast<size_t>(r.identified);
    if (++k == d.exposures.size()) {
      state.PauseTiming();
      k = 0;
      matcher.reset_tracking();
      state.ResumeTiming();
    }
  }
  state.counters["identified"] =
      benchmark::Counter(static_cast<double>(identified), benchmark::Counter::kAvgIterations);
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Match);

// Everything after alignment: matching + triangulation + rigid-body checks + poses + full
// covariance and budget + FtiSample. Exposures are replayed in order (tracking stays valid);
// at the end of the scenario the processor restarts from its priors (not timed).
void BM_ExposureMatchAndProcess(benchmark::State& state) {
  const Data& d = data();
  auto proc = make_processor(d);
  size_t k = 0, marks = 0;
  for (auto _ : state) {
    const pipeline::ExposureResult r = proc.process(d.exposures[k]);
    benchmark::DoNotOptimize(r.sample);
    marks += r.marks.size();
    if (++k == d.exposures.size()) {
      state.PauseTiming();
      k = 0;
      proc.reset_tracking();
      state.ResumeTiming();
    }
  }
  state.counters["marks"] =
      benchmark::Counter(static_cast<double>(marks), benchmark::Counter::kAvgIterations);
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_ExposureMatchAndProcess);

// The same with the simulator's truth ids (no matching): the geometry and uncertainty alone.
void BM_ExposureProcessKnownIds(benchmark::State& state) {
  const Data& d = data();
  auto proc = make_processor(d);
  size_t k = 0, marks = 0;
  for (auto _ : state) {
    const pipeline::ExposureResult r = proc.process(d.exposures[k], d.truth_ids[k]);
    benchmark::DoNotOptimize(r.sample);
    marks += r.marks.size();
    k = (k + 1) % d.exposures.size();
  }
  state.counters["marks"] =
      benchmark::Counter(static_cast<double>(marks), benchmark::Counter::kAvgIterations);
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_ExposureProcessKnownIds);

// Two-view points of one exposure (cameras 0 and 1), for the per-point comparison.
struct TwoView {
  std::vector<geometry::Vec2> px0, px1;
  std::vector<double> sigma0, sigma1;
};

TwoView two_view(const Data& d, int k) {
  TwoView tv;
  const auto& ex = d.exposures[static_cast<size_t>(k)];
  const auto& ids = d.truth_ids[static_cast<size_t>(k)];
  for (size_t j = 0; j < ids[0].size(); ++j) {
    if (ids[0][j] < 0) continue;
    for (size_t i = 0; i < ids[1].size(); ++i)
      if (ids[1][i] == ids[0][j]) {
        tv.px0.emplace_back(ex.cameras[0].marks[j].x_px, ex.cameras[0].marks[j].y_px);
        tv.px1.emplace_back(ex.cameras[1].marks[i].x_px, ex.cameras[1].marks[i].y_px);
        tv.sigma0.push_back(ex.cameras[0].marks[j].sigma_px);
        tv.sigma1.push_back(ex.cameras[1].marks[i].sigma_px);
      }
  }
  return tv;
}

// storetrack: undistortion + linear initialisation + Gauss-Newton + covariance + gains +
// full Jacobians (what the pipeline uses), per point.
void BM_TriangulateRefinedWithCovariance2Views(benchmark::State& state) {
  triangulate::Options options;
  options.calibration_jacobians = state.range(0) != 0;
  const Data& d = data();
  const auto rig = d.sim.calibrated_rig();
  const TwoView tv = two_view(d, d.sim.num_exposures() / 2);
  triangulate::Observation obs[2];
  obs[0].model = &rig.cameras[0].model;
  obs[0].T_c_w = rig.cameras[0].T_c_w;
  obs[1].model = &rig.cameras[1].model;
  obs[1].T_c_w = rig.cameras[1].T_c_w;
  triangulate::Result r;
  size_t i = 0;
  for (auto _ : state) {
    obs[0].pixel_px = tv.px0[i];
    obs[1].pixel_px = tv.px1[i];
    obs[0].sigma_px = tv.sigma0[i];
    obs[1].sigma_px = tv.sigma1[i];
    benchmark::DoNotOptimize(triangulate::triangulate(obs, options, r));
    benchmark::DoNotOptimize(r.cov_centroid);
    i = (i + 1) % tv.px0.size();
  }
  state.SetItemsProcessed(state.iterations());
}
// Arg 1: with the calibration Jacobians (as the pipeline runs it); arg 0: refinement +
// centroid covariance only.
BENCHMARK(BM_TriangulateRefinedWithCovariance2Views)->Arg(1)->Arg(0);

cv::Matx34d projection(const camera::CalibratedCamera& cam) {
  const auto& in = cam.model.intrinsics();
  const cv::Matx33d K(in.fx, in.skew, in.cx, 0, in.fy, in.cy, 0, 0, 1);
  cv::Matx34d Rt;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c)
      Rt(r, c) = cam.T_c_w.linear()(r, c);
    Rt(r, 3) = cam.T_c_w.translation()(r);
  }
  return K * Rt;
}

// OpenCV, linear only (DLT, no distortion, no refinement, no covariance): one call per point.
void BM_CvTriangulatePoints2ViewsPerCall(benchmark::State& state) {
  const Data& d = data();
  const auto rig = d.sim.calibrated_rig();
  const TwoView tv = two_view(d, d.sim.num_exposures() / 2);
  const cv::Mat P0(projection(rig.cameras[0])), P1(projection(rig.cameras[1]));
  cv::Mat x0(2, 1, CV_64F), x1(2, 1, CV_64F), X;
  size_t i = 0;
  for (auto _ : state) {
    x0.at<double>(0) = tv.px0[i].x();
    x0.at<double>(1) = tv.px0[i].y();
    x1.at<double>(0) = tv.px1[i].x();
    x1.at<double>(1) = tv.px1[i].y();
    cv::triangulatePoints(P0, P1, x0, x1, X);
    benchmark::DoNotOptimize(X.data);
    i = (i + 1) % tv.px0.size();
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_CvTriangulatePoints2ViewsPerCall);

// OpenCV with all points of the exposure in one call (its best case); items = points.
void BM_CvTriangulatePoints2ViewsBatch(benchmark::State& state) {
  const Data& d = data();
  const auto rig = d.sim.calibrated_rig();
  const TwoView tv = two_view(d, d.sim.num_exposures() / 2);
  const cv::Mat P0(projection(rig.cameras[0])), P1(projection(rig.cameras[1]));
  const int n = static_cast<int>(tv.px0.size());
  cv::Mat x0(2, n, CV_64F), x1(2, n, CV_64F), X;
  for (int i = 0; i < n; ++i) {
    x0.at<double>(0, i) = tv.px0[static_cast<size_t>(i)].x();
    x0.at<double>(1, i) = tv.px0[static_cast<size_t>(i)].y();
    x1.at<double>(0, i) = tv.px1[static_cast<size_t>(i)].x();
    x1.at<double>(1, i) = tv.px1[static_cast<size_t>(i)].y();
  }
  for (auto _ : state) {
    cv::triangulatePoints(P0, P1, x0, x1, X);
    benchmark::DoNotOptimize(X.data);
  }
  state.SetItemsProcessed(state.iterations() * n);
}
BENCHMARK(BM_CvTriangulatePoints2ViewsBatch);

}  // namespace

BENCHMARK_MAIN();
