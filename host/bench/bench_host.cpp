// storetrack-host-bench: cost of one exposure on the host (4 cameras, 23 marks, store
// separation from the simulator's fast mode): identification alone, identification +
// geometry, geometry with known ids; and triangulation per point against OpenCV's
// linear cv::triangulatePoints on the same observations (docs/performance.md, "Host processing").
// BM_HostScaling*: the processor and cv::triangulatePoints over 2..8 cameras x 8..64 store
// marks (docs/performance.md, "Host scaling over cameras x marks").
#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <benchmark/benchmark.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "simulated_exposures.hpp"
#include "storetrack/clearance/sample_clearance.hpp"
#include "storetrack/match/mark_matcher.hpp"
#include "storetrack/pipeline/calibration_health.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/sim/simulator.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "synthetic_meshes.hpp"

namespace {

using namespace storetrack;

using Data = bench::SimulatedExposures;
using bench::make_processor;

const Data& data() {
  return bench::store_separation();
}

pipeline::ExposureProcessor make_processor(const Data& d) {
  return make_processor(d.sim);
}

// Steps k to the next of n exposures; after the last one `restart` (tracking from the priors
// again) runs untimed and k wraps to the first.
template <class Restart>
void next_exposure(benchmark::State& state, size_t& k, size_t n, Restart&& restart) {
  if (++k != n) return;
  state.PauseTiming();
  k = 0;
  restart();
  state.ResumeTiming();
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
    next_exposure(state, k, d.exposures.size(), [&] { matcher.reset_tracking(); });
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
    next_exposure(state, k, d.exposures.size(), [&] { proc.reset_tracking(); });
  }
  state.counters["marks"] =
      benchmark::Counter(static_cast<double>(marks), benchmark::Counter::kAvgIterations);
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_ExposureMatchAndProcess);

// BM_ExposureMatchAndProcess with the store-to-aircraft clearance on (/1) beside off (/0), as
// the host loop adds it (docs/clearance.md, "In the host"): the clearance benchmark's meshes, a
// 5 000-triangle store against a 20 000-triangle wing and pylon, evaluated per sample with its
// pose and covariance (every part, the lowest bound into the sample, the alarm bit).
void BM_ExposureMatchAndProcessClearance(benchmark::State& state) {
  const Data& d = data();
  auto proc = make_processor(d);
  std::unique_ptr<clearance::SampleClearance> sample_clearance;
  if (state.range(0) != 0)
    sample_clearance = std::make_unique<clearance::SampleClearance>(
        clearance::ClearanceModel(
            {{"store", clearance::BodyFrame::kStore, test::store(3.0, 0.2, 78, 32)},
             {"aircraft", clearance::BodyFrame::kPylon, test::aircraft(100, 100, 0.6)}}),
        0.1);
  size_t k = 0;
  double clearance_sum = 0, u_sum = 0, candidate_pairs = 0;
  std::uint64_t evaluated = 0;
  for (auto _ : state) {
    pipeline::ExposureResult r = proc.process(d.exposures[k]);
    if (sample_clearance && r.T_p_s.valid) {
      sample_clearance->apply(r.T_p_s.T, r.T_p_s.cov, r.sample);
      clearance_sum += r.sample.clearance_m;
      u_sum += r.sample.u_clearance_m;
      candidate_pairs += sample_clearance->parts().front().candidate_pairs;
      ++evaluated;
    }
    benchmark::DoNotOptimize(r.sample);
    next_exposure(state, k, d.exposures.size(), [&] { proc.reset_tracking(); });
  }
  if (evaluated > 0) {
    const auto n = static_cast<double>(evaluated);
    state.counters["mean_clearance_m"] = clearance_sum / n;
    state.counters["mean_u_clearance_m"] = u_sum / n;
    state.counters["mean_candidate_pairs"] = candidate_pairs / n;
  }
  state.counters["evaluated"] =
      benchmark::Counter(static_cast<double>(evaluated), benchmark::Counter::kAvgIterations);
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_ExposureMatchAndProcessClearance)->Arg(0)->Arg(1);

// The host's clearance cost taken apart: the poses and covariances that the processor fits over
// the store separation (collected once, not timed), then SampleClearance::apply alone on them in
// exposure order with the trees hot in cache. Beside BM_ExposureMatchAndProcessClearance/1 - /0 it
// tells the cost of the poses themselves from that of the processor evicting the trees.
struct FittedPose {
  geometry::Transform T_p_s;
  geometry::Mat6 cov;
};
const std::vector<FittedPose>& fitted_poses() {
  static const std::vector<FittedPose> poses = [] {
    const Data& d = data();
    auto proc = make_processor(d);
    std::vector<FittedPose> out;
    for (const pipeline::AlignedExposure& ex : d.exposures) {
      const pipeline::ExposureResult r = proc.process(ex);
      if (r.T_p_s.valid) out.push_back({r.T_p_s.T, r.T_p_s.cov});
    }
    return out;
  }();
  return poses;
}

void BM_ClearanceAtHostPoses(benchmark::State& state) {
  const std::vector<FittedPose>& poses = fitted_poses();
  clearance::SampleClearance sample_clearance(
      clearance::ClearanceModel(
          {{"store", clearance::BodyFrame::kStore, test::store(3.0, 0.2, 78, 32)},
           {"aircraft", clearance::BodyFrame::kPylon, test::aircraft(100, 100, 0.6)}}),
      0.1);
  std::size_t k = 0;
  double candidate_pairs = 0;
  for (auto _ : state) {
    msg::FtiSample sample{};
    sample_clearance.apply(poses[k].T_p_s, poses[k].cov, sample);
    benchmark::DoNotOptimize(sample);
    candidate_pairs += sample_clearance.parts().front().candidate_pairs;
    if (++k == poses.size()) k = 0;
  }
  state.counters["poses"] = static_cast<double>(poses.size());
  state.counters["mean_candidate_pairs"] =
      benchmark::Counter(candidate_pairs, benchmark::Counter::kAvgIterations);
}
BENCHMARK(BM_ClearanceAtHostPoses)->Unit(benchmark::kMicrosecond);

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

// The calibration health test per exposure (docs/calibration-health.md): the guard's filter and
// observe on the processor's results (computed before timing), i.e. what the host adds to
// BM_ExposureMatchAndProcess. Windows of 10 after 2 (the test runs every 10 exposures).
void BM_CalibrationHealthObserve(benchmark::State& state) {
  const Data& d = data();
  auto proc = make_processor(d);
  std::vector<pipeline::ExposureResult> results;
  for (const auto& e : d.exposures)
    results.push_back(proc.process(e));
  pipeline::CalibrationHealthConfig config;
  config.window_exposures = 10;
  config.baseline_windows = 2;
  pipeline::CalibrationHealthGuard guard(d.sim.calibrated_rig(), d.sim.pylon_survey(), config,
                                         pipeline::CalibrationHealthMode::kFlag);
  size_t k = 0;
  for (auto _ : state) {
    const pipeline::AlignedExposure& e = guard.filter(d.exposures[k]);
    benchmark::DoNotOptimize(guard.observe(e, results[k]));
    k = (k + 1) % d.exposures.size();
  }
  state.counters["windows_tested"] =
      static_cast<double>(guard.monitor().cameras().front().windows_tested);
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_CalibrationHealthObserve);

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

// ---- Host scaling over cameras x marks (docs/performance.md, "Host scaling over cameras x
// marks"; tools/bench-host-scaling runs these and fits cost = a + b * cameras * marks).
//
// The store-separation scenario modified in code the way tests/integration/faults/run_soak.py's
// scenario() does it: a second camera beside each of the 4 (0.25 m aft, 0.05 m lower, same
// aim and unit) and rings of 8 extra store marks around the body. Fewer cameras are a subset of
// the 8 and fewer marks a subset of the 64-mark survey, so every configuration is the same scene
// seen by more or fewer cameras and marks. The store separates as in the scenario file.

constexpr int kScalingRingMarks = 8;
constexpr int kScalingRings = 6;  // 16 + 6 x 8 = 64 store marks: the largest survey
// Rings taken in this order (a subset of n rings spreads along the body: 2 = both ends).
constexpr std::array<int, kScalingRings> kScalingRingOrder = {0, 5, 2, 3, 1, 4};
// Cameras beside these ones are taken in this order after the scenario's 4 (so 4 cameras is
// BM_ExposureMatchAndProcess's rig and 6 cameras add one on each side of the pylon).
constexpr std::array<int, 4> kScalingBesideOrder = {0, 2, 1, 3};

std::vector<sim::CameraSetup> scaling_cameras(const std::vector<sim::CameraSetup>& original,
                                              int count) {
  std::vector<sim::CameraSetup> cameras = original;
  for (const int i : kScalingBesideOrder) {
    sim::CameraSetup beside = original.at(static_cast<size_t>(i));
    beside.position_p_m += geometry::Vec3(-0.25, 0.0, 0.05);
    cameras.push_back(beside);
  }
  if (count < 1 || count > static_cast<int>(cameras.size()))
    throw std::invalid_argument("bench: 1..8 cameras");
  cameras.resize(static_cast<size_t>(count));
  for (size_t i = 0; i < cameras.size(); ++i)
    cameras[i].camera_id = static_cast<int>(i);
  return cameras;
}

// run_soak.py's rings (--mark-stations 6): 8 marks around the store at each of 6 stations
// from x = -0.9 to 0.9 m, ids after the scenario's store marks, in station order.
std::vector<survey::SurveyedMark> scaling_rings(const sim::Scenario& scenario) {
  int next_id = 0;
  for (const survey::SurveyedMark& m : scenario.store.marks)
    next_id = std::max(next_id, m.id + 1);
  const double radius = scenario.store_shape.radius_m;
  std::vector<survey::SurveyedMark> rings;
  for (int k = 0; k < kScalingRings; ++k) {
    const double x = -0.9 + 1.8 / (kScalingRings - 1) * k;
    for (int j = 0; j < kScalingRingMarks; ++j) {
      const double angle = 2 * M_PI * (j + 0.37 * k) / kScalingRingMarks;
      rings.push_back({next_id++,
                       geometry::Vec3(x, radius * std::sin(angle), radius * std::cos(angle)),
                       0.0002});
    }
  }
  return rings;
}

// Half of the scenario's 16 store marks (every other: 2 of the 4 at each station), all 16, or
// all 16 plus 1..6 rings.
std::vector<survey::SurveyedMark> scaling_store_marks(const sim::Scenario& scenario, int count) {
  const std::vector<survey::SurveyedMark>& original = scenario.store.marks;
  const int n_original = static_cast<int>(original.size());
  std::vector<survey::SurveyedMark> marks;
  if (count * 2 == n_original) {
    for (size_t i = 0; i < original.size(); i += 2)
      marks.push_back(original[i]);
    return marks;
  }
  const int extra = count - n_original;
  if (extra < 0 || extra % kScalingRingMarks != 0 || extra > kScalingRings * kScalingRingMarks)
    throw std::invalid_argument("bench: store marks must be 8, 16 or 16 + 8 n up to 64");
  marks = original;
  const std::vector<survey::SurveyedMark> rings = scaling_rings(scenario);
  for (int r = 0; r < extra / kScalingRingMarks; ++r) {
    const auto first =
        rings.begin() + kScalingRingOrder[static_cast<size_t>(r)] * kScalingRingMarks;
    marks.insert(marks.end(), first, first + kScalingRingMarks);
  }
  return marks;
}

sim::Scenario scaling_scenario(int cameras, int store_marks) {
  sim::Scenario scenario =
      sim::load_scenario(std::string(STORETRACK_SCENARIO_DIR) + "/store_separation.json");
  scenario.cameras = scaling_cameras(scenario.cameras, cameras);
  scenario.store.marks = scaling_store_marks(scenario, store_marks);
  return scenario;
}

// All points of one exposure that cv::triangulatePoints gets from one camera pair in one call
// (its best case): normalised, undistorted image points (2 x n), projections [R | t].
struct PairBatch {
  int camera_a = 0, camera_b = 0;  // camera indices (= camera ids here)
  cv::Mat x_a, x_b, X;
};

using PairPoints = std::map<std::pair<int, int>, std::vector<Eigen::Vector4d>>;

std::vector<PairBatch> to_batches(const PairPoints& points) {
  std::vector<PairBatch> batches;
  for (const auto& [pair, xy] : points) {
    PairBatch b;
    b.camera_a = pair.first;
    b.camera_b = pair.second;
    const int n = static_cast<int>(xy.size());
    b.x_a.create(2, n, CV_64F);
    b.x_b.create(2, n, CV_64F);
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector4d& p = xy[static_cast<size_t>(i)];
      b.x_a.at<double>(0, i) = p(0);
      b.x_a.at<double>(1, i) = p(1);
      b.x_b.at<double>(0, i) = p(2);
      b.x_b.at<double>(1, i) = p(3);
    }
    b.X.create(4, n, CV_64F);  // the output allocated once, as a caller reusing it would
    batches.push_back(std::move(b));
  }
  return batches;
}

cv::Mat normalised_projection(const camera::CalibratedCamera& cam) {
  cv::Mat Rt(3, 4, CV_64F);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c)
      Rt.at<double>(r, c) = cam.T_c_w.linear()(r, c);
    Rt.at<double>(r, 3) = cam.T_c_w.translation()(r);
  }
  return Rt;
}

// One configuration, built once (the simulator costs far more than the benchmark): its
// exposures, one untimed pass of the processor for the counters and the OpenCV peer's inputs.
// The peer triangulates the observations the processor used for each of its marks (its own
// identification, not the simulator's truth), undistorted by the host's camera model before
// timing: first_pair = each mark once, from the first two cameras that saw it (one point per
// mark, as the processor outputs); all_pairs = each mark from every pair of its cameras.
struct ScalingData {
  ScalingData(int cameras, int store_marks);

  sim::Simulator sim;
  int marks = 0;  // pylon + store marks of the surveys
  std::vector<pipeline::AlignedExposure> exposures;
  double observations = 0, identified = 0, triangulated = 0;  // per exposure, untimed pass
  std::vector<cv::Mat> projections;                           // per camera index
  std::vector<std::vector<PairBatch>> first_pair, all_pairs;  // per exposure
  double first_pair_points = 0, all_pairs_points = 0;         // per exposure
  // That the peer computes the same points: distance of its first-pair point from the
  // processor's mark position, median and largest over the scenario [mm].
  double peer_median_difference_mm = 0, peer_max_difference_mm = 0;
  std::vector<double> peer_differences_mm;

 private:
  void add_peer_inputs(const camera::RigCalibration& rig, const pipeline::AlignedExposure& ex,
                       const pipeline::ExposureResult& r);
};

ScalingData::ScalingData(int cameras, int store_marks)
    : sim(scaling_scenario(cameras, store_marks), 3) {
  marks = static_cast<int>(sim.scenario().pylon.marks.size() + sim.scenario().store.marks.size());
  for (int k = 0; k < sim.num_exposures(); ++k) {
    pipeline::AlignedExposure ex;
    ex.cameras.resize(static_cast<size_t>(sim.num_cameras()));
    for (int c = 0; c < sim.num_cameras(); ++c)
      sim.observe(k, c, ex.cameras[static_cast<size_t>(c)]);
    ex.trigger_seq = ex.cameras[0].trigger_seq;
    exposures.push_back(ex);
  }
  const camera::RigCalibration rig = sim.calibrated_rig();
  for (const camera::CalibratedCamera& cam : rig.cameras)
    projections.push_back(normalised_projection(cam));
  auto proc = make_processor(sim);
  for (const pipeline::AlignedExposure& ex : exposures) {
    const std::uint64_t identified_before = proc.matcher().counters().identified;
    const pipeline::ExposureResult r = proc.process(ex);
    identified += static_cast<double>(proc.matcher().counters().identified - identified_before);
    triangulated += static_cast<double>(r.marks.size());
    for (const msg::MarkObservations& obs : ex.cameras)
      observations += obs.mark_count;
    add_peer_inputs(rig, ex, r);
  }
  const double n = static_cast<double>(exposures.size());
  observations /= n;
  identified /= n;
  triangulated /= n;
  first_pair_points /= n;
  all_pairs_points /= n;
  if (!peer_differences_mm.empty()) {
    std::sort(peer_differences_mm.begin(), peer_differences_mm.end());
    peer_median_difference_mm = peer_differences_mm[peer_differences_mm.size() / 2];
    peer_max_difference_mm = peer_differences_mm.back();
  }
}

// One point through cv::triangulatePoints (untimed check of the peer's inputs).
geometry::Vec3 dlt_point(const cv::Mat& P_a, const cv::Mat& P_b, const Eigen::Vector4d& xy) {
  const cv::Mat x_a = (cv::Mat_<double>(2, 1) << xy(0), xy(1));
  const cv::Mat x_b = (cv::Mat_<double>(2, 1) << xy(2), xy(3));
  cv::Mat X;
  cv::triangulatePoints(P_a, P_b, x_a, x_b, X);
  return geometry::Vec3(X.at<double>(0), X.at<double>(1), X.at<double>(2)) / X.at<double>(3);
}

void ScalingData::add_peer_inputs(const camera::RigCalibration& rig,
                                  const pipeline::AlignedExposure& ex,
                                  const pipeline::ExposureResult& r) {
  PairPoints first, all;
  for (const pipeline::MarkResult& mark : r.marks) {
    std::vector<std::pair<int, geometry::Vec2>> seen;  // (camera index, normalised point)
    for (const auto& o : mark.observations) {
      const msg::MarkObservation& m =
          ex.cameras[static_cast<size_t>(o.camera_id)].marks[static_cast<size_t>(o.mark_index)];
      const auto xy = rig.cameras[static_cast<size_t>(o.camera_id)].model.unproject(
          geometry::Vec2(m.x_px, m.y_px));
      if (xy) seen.emplace_back(o.camera_id, *xy);
    }
    std::sort(seen.begin(), seen.end(),
              [](const auto& a, const auto& b) { return a.first < b.first; });
    for (size_t i = 0; i < seen.size(); ++i)
      for (size_t j = i + 1; j < seen.size(); ++j) {
        const Eigen::Vector4d xy(seen[i].second.x(), seen[i].second.y(), seen[j].second.x(),
                                 seen[j].second.y());
        all[{seen[i].first, seen[j].first}].push_back(xy);
        if (i == 0 && j == 1) {
          first[{seen[i].first, seen[j].first}].push_back(xy);
          const geometry::Vec3 p_w = dlt_point(projections[static_cast<size_t>(seen[i].first)],
                                               projections[static_cast<size_t>(seen[j].first)], xy);
          peer_differences_mm.push_back(1e3 * (p_w - mark.p_w).norm());
        }
        all_pairs_points += 1;
        first_pair_points += i == 0 && j == 1 ? 1 : 0;
      }
  }
  first_pair.push_back(to_batches(first));
  all_pairs.push_back(to_batches(all));
}

ScalingData& scaling_data(int cameras, int store_marks) {
  static std::map<std::pair<int, int>, std::unique_ptr<ScalingData>> cache;
  auto& d = cache[{cameras, store_marks}];
  if (!d) d = std::make_unique<ScalingData>(cameras, store_marks);
  return *d;
}

void set_scaling_counters(benchmark::State& state, const ScalingData& d) {
  const double cameras = static_cast<double>(d.sim.num_cameras());
  state.counters["cameras"] = cameras;
  state.counters["marks"] = d.marks;
  state.counters["store_marks"] = static_cast<double>(d.sim.scenario().store.marks.size());
  state.counters["cameras_x_marks"] = cameras * d.marks;
  state.counters["observations"] = d.observations;
  state.counters["identified"] = d.identified;
  state.counters["triangulated"] = d.triangulated;
  state.SetItemsProcessed(state.iterations());
}

// ExposureProcessor::process with its MarkMatcher, as BM_ExposureMatchAndProcess: exposures
// replayed in order, the processor restarted from its priors at the end (not timed).
// Times `proc` over the configuration's exposures, tracking restarted after the last one.
void time_processing(benchmark::State& state, pipeline::ExposureProcessor& proc, ScalingData& d) {
  size_t k = 0;
  pipeline::ExposureResult r;  // reused, as the host loop and the replay do
  for (auto _ : state) {
    proc.process(d.exposures[k], r);
    benchmark::DoNotOptimize(r.sample);
    next_exposure(state, k, d.exposures.size(), [&] { proc.reset_tracking(); });
  }
  set_scaling_counters(state, d);
}

void BM_HostScalingProcess(benchmark::State& state, int cameras, int store_marks) {
  ScalingData& d = scaling_data(cameras, store_marks);
  auto proc = make_processor(d.sim);
  time_processing(state, proc, d);
}

// The same with a version-2 calibration whose joint covariance couples every camera (a shared
// world registration, 0.1 mrad / 0.3 mm per axis) and each camera's principal point with its
// rotation (correlation 0.9): the dense case, each camera's extrinsics loading on all
// intrinsic and extrinsic factor columns (issue 9: the cost of the cross terms).
camera::RigCalibration with_joint_covariance(camera::RigCalibration rig) {
  constexpr int kB = camera::kJointBlockSize, kI = camera::kNumIntrinsics;
  const auto n = static_cast<Eigen::Index>(rig.cameras.size());
  Eigen::MatrixXd joint = rig.full_joint_covariance();
  Eigen::MatrixXd D = Eigen::MatrixXd::Zero(kB * n, 6);
  for (Eigen::Index c = 0; c < n; ++c) {
    const geometry::Mat3 R = rig.cameras[static_cast<size_t>(c)].T_c_w.linear();
    D.block<3, 3>(kB * c + kI, 0) = R;
    D.block<3, 3>(kB * c + kI + 3, 3) = R;
    const Eigen::Index cx = kB * c + 2, ry = kB * c + kI + 1;
    joint(cx, ry) = joint(ry, cx) = 0.9 * std::sqrt(joint(cx, cx) * joint(ry, ry));
  }
  geometry::Vec6 sd;
  sd << 1e-4, 1e-4, 1e-4, 3e-4, 3e-4, 3e-4;
  camera::set_joint_covariance(rig, joint + D * sd.cwiseAbs2().asDiagonal() * D.transpose());
  return rig;
}

void BM_HostScalingProcessJoint(benchmark::State& state, int cameras, int store_marks) {
  ScalingData& d = scaling_data(cameras, store_marks);
  const sim::Simulator& sim = d.sim;
  pipeline::ExposureProcessor proc(with_joint_covariance(sim.calibrated_rig()), sim.pylon_survey(),
                                   sim.store_survey(), pipeline::ProcessorConfig{});
  geometry::Mat6 prior = geometry::Mat6::Identity() * 1e-4;
  proc.matcher().set_prior_pose("pylon", sim.scenario().T_w_p, prior);
  proc.matcher().set_prior_pose("store", sim.scenario().T_w_p * sim.scenario().separation.T_p_s0,
                                prior);
  time_processing(state, proc, d);
  state.counters["factors"] = proc.factors().num_factors();
}

// The peer on the same exposures: one cv::triangulatePoints call per camera pair and exposure
// (linear DLT only: no distortion, refinement or covariance).
void BM_HostScalingCvTriangulate(benchmark::State& state, int cameras, int store_marks,
                                 bool all_pairs) {
  ScalingData& d = scaling_data(cameras, store_marks);
  std::vector<std::vector<PairBatch>>& batches = all_pairs ? d.all_pairs : d.first_pair;
  size_t k = 0;
  for (auto _ : state) {
    for (PairBatch& b : batches[k]) {
      cv::triangulatePoints(d.projections[static_cast<size_t>(b.camera_a)],
                            d.projections[static_cast<size_t>(b.camera_b)], b.x_a, b.x_b, b.X);
      benchmark::DoNotOptimize(b.X.data);
    }
    k = (k + 1) % batches.size();
  }
  set_scaling_counters(state, d);
  state.counters["points"] = all_pairs ? d.all_pairs_points : d.first_pair_points;
  state.counters["first_pair_vs_process_median_mm"] = d.peer_median_difference_mm;
  state.counters["first_pair_vs_process_max_mm"] = d.peer_max_difference_mm;
}

// Each configuration's three benchmarks registered side by side, so a drift of the machine's
// speed during the run hits the processor and its peer alike.
const bool scaling_registered = [] {
  for (const int cameras : {2, 4, 6, 8})
    for (const int store_marks : {8, 16, 32, 64}) {
      const std::string config =
          "/cameras:" + std::to_string(cameras) + "/store_marks:" + std::to_string(store_marks);
      benchmark::RegisterBenchmark(("BM_HostScalingProcess" + config).c_str(),
                                   BM_HostScalingProcess, cameras, store_marks);
      benchmark::RegisterBenchmark(("BM_HostScalingProcessJoint" + config).c_str(),
                                   BM_HostScalingProcessJoint, cameras, store_marks);
      benchmark::RegisterBenchmark(("BM_HostScalingCvFirstPair" + config).c_str(),
                                   BM_HostScalingCvTriangulate, cameras, store_marks, false);
      benchmark::RegisterBenchmark(("BM_HostScalingCvAllPairs" + config).c_str(),
                                   BM_HostScalingCvTriangulate, cameras, store_marks, true);
    }
  return true;
}();

}  // namespace

BENCHMARK_MAIN();
