// storetrack-calib-bench: single-camera intrinsic calibration, storetrack's
// calib::calibrate_intrinsics (the entry point of `storetrack-calib intrinsic`: Zhang start,
// Ceres LM, residuals and the parameter covariance) against cv::calibrateCamera with the same
// model on the same observations (docs/performance.md, "Intrinsic calibration").
// Cases: the 13 left images of OpenCV's 9x6 chessboard set (tests/data; corners detected once
// in the set-up, not timed; flags of its REFERENCE.md: fixed aspect ratio, 5 coefficients) and a
// synthetic set of 150 views x 100 points (tests/host/calib/synthetic_board.hpp; the
// 5-coefficient model k1, k2, p1, p2, k3 with fx, fy, cx, cy free, no outlier rejection either
// side).
// Wide angle: OpenCV's fisheye stereo set (tests/data/opencv_fisheye_stereo_jy, 34 views x 48
// corners a camera), the Kannala-Brandt model against cv::fisheye::calibrate with the flags of
// OpenCV's fisheyeTest.Calibration (as tests/host/calib/test_fisheye_stereo_jy.cpp).
#include <time.h>

#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <random>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "storetrack/calib/chessboard_detection.hpp"
#include "storetrack/calib/intrinsic_calibration.hpp"
#include "storetrack/calib/observations.hpp"
#include "synthetic_board.hpp"

namespace {

using namespace storetrack;

/// One calibration problem in both libraries' input forms, and both sides' options.
struct Case {
  calib::ObservationSet set;
  calib::IntrinsicOptions options;
  std::vector<std::vector<cv::Point3f>> object_points;  // per view
  std::vector<std::vector<cv::Point2f>> image_points;
  cv::Size image_size;
  int cv_flags = 0;
};

void fill_opencv_input(Case& c) {
  std::map<int, size_t> view_of_frame;
  for (const calib::Observation& o : c.set.observations) {
    const auto [it, added] = view_of_frame.emplace(o.frame, c.object_points.size());
    if (added) {
      c.object_points.emplace_back();
      c.image_points.emplace_back();
    }
    c.object_points[it->second].emplace_back(static_cast<float>(o.p_board.x()),
                                             static_cast<float>(o.p_board.y()),
                                             static_cast<float>(o.p_board.z()));
    c.image_points[it->second].emplace_back(static_cast<float>(o.pixel.x()),
                                            static_cast<float>(o.pixel.y()));
  }
  const calib::ImageSize size = c.set.image_sizes.at(0);
  c.image_size = cv::Size(size.width, size.height);
}

Case opencv_chessboard_set() {
  const std::string set = std::string(STORETRACK_TEST_DATA_DIR) + "/opencv_stereo_chessboard_9x6";
  std::vector<std::string> images;
  for (int i : {1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14}) {  // no left10 upstream
    char name[32];
    std::snprintf(name, sizeof name, "/images/left%02d.jpg", i);
    images.push_back(set + name);
  }
  Case c;
  c.set = calib::detect_chessboards(images, {9, 6, 0.025}, 0).set;
  c.options.fix_aspect_ratio = true;  // REFERENCE.md: flags = CALIB_FIX_ASPECT_RATIO, ratio 1
  c.options.outlier_false_alarm = 0;  // cv::calibrateCamera keeps every point
  c.options.board_deflection = calib::BoardDeflection::off;  // its board is flat
  c.cv_flags = cv::CALIB_FIX_ASPECT_RATIO;
  fill_opencv_input(c);
  return c;
}

constexpr int kSyntheticViews = 150;
constexpr double kSyntheticNoisePx = 0.2;

/// 150 views of a 10 x 10 board (40 mm squares), each with all 100 corners in the image: poses
/// of the tests' sequence that lose a corner off the image are skipped.
Case synthetic_set() {
  const calib::test::BoardGrid grid{10, 10, 0.04};
  const camera::CameraModel model(calib::test::truth_camera());
  std::mt19937_64 rng(9);
  std::normal_distribution<double> noise(0, kSyntheticNoisePx);
  Case c;
  c.set.image_sizes[0] = {1920, 1024};
  for (int pose = 0, views = 0; views < kSyntheticViews; ++pose) {
    calib::ObservationSet view;
    calib::test::add_board_view(model, calib::test::board_pose(pose, false, grid), 0, views, noise,
                                rng, view, grid);
    if (view.observations.size() != 100) continue;
    c.set.observations.insert(c.set.observations.end(), view.observations.begin(),
                              view.observations.end());
    ++views;
  }
  c.options.outlier_false_alarm = 0;                         // as OpenCV: every point kept
  c.options.board_deflection = calib::BoardDeflection::off;  // as OpenCV: a flat board
  c.cv_flags = 0;                                            // fx, fy, cx, cy, k1, k2, p1, p2, k3
  fill_opencv_input(c);
  return c;
}

/// The OpenCV set with `storetrack-calib intrinsic`'s default outlier gate (what the program runs;
/// it rejects left02's first corner column, so the fit runs twice and its RMS is lower).
Case opencv_chessboard_set_program_defaults() {
  Case c = opencv_chessboard_set();
  c.options.outlier_false_alarm = calib::IntrinsicOptions{}.outlier_false_alarm;
  c.options.board_deflection = calib::IntrinsicOptions{}.board_deflection;  // auto: the bowl
  return c;
}

enum CaseId : int { kOpenCvSet = 0, kSynthetic = 1, kOpenCvSetProgramDefaults = 2 };

const Case& get_case(int which) {
  static const Case opencv = opencv_chessboard_set();
  static const Case synthetic = synthetic_set();
  static const Case opencv_defaults = opencv_chessboard_set_program_defaults();
  return which == kOpenCvSet ? opencv : which == kSynthetic ? synthetic : opencv_defaults;
}

const char* case_name(int which) {
  return which == kOpenCvSet   ? "opencv_9x6_left"
         : which == kSynthetic ? "synthetic_150x100"
                               : "opencv_9x6_left outlier gate on (program default)";
}

double storetrack_rms(const Case& c) {
  return calib::calibrate_intrinsics(c.set, 0, c.options).rms_px;
}

/// extended: also OpenCV's parameter standard deviations and per-view errors (its counterpart of
/// the covariance and per-view residuals that storetrack always computes).
double opencv_rms(const Case& c, bool extended) {
  cv::Mat K = cv::Mat::eye(3, 3, CV_64F);  // with FIX_ASPECT_RATIO: fx / fy = 1 (the sample's)
  cv::Mat dist, std_intrinsics, std_extrinsics, per_view;
  std::vector<cv::Mat> rvecs, tvecs;
  if (extended)
    return cv::calibrateCamera(c.object_points, c.image_points, c.image_size, K, dist, rvecs, tvecs,
                               std_intrinsics, std_extrinsics, per_view, c.cv_flags);
  return cv::calibrateCamera(c.object_points, c.image_points, c.image_size, K, dist, rvecs, tvecs,
                             c.cv_flags);
}

void BM_StoretrackIntrinsic(benchmark::State& state) {
  const Case& c = get_case(static_cast<int>(state.range(0)));
  state.SetLabel(case_name(static_cast<int>(state.range(0))));
  calib::IntrinsicResult r;
  for (auto _ : state)
    benchmark::DoNotOptimize(r = calib::calibrate_intrinsics(c.set, 0, c.options));
  state.counters["rms_px"] = r.rms_px;
  state.counters["lm_iterations"] = r.iterations;
  state.counters["points"] = r.points_used;
}
BENCHMARK(BM_StoretrackIntrinsic)
    ->Arg(kOpenCvSet)
    ->Arg(kSynthetic)
    ->Arg(kOpenCvSetProgramDefaults)
    ->Unit(benchmark::kMillisecond);

void BM_CvCalibrateCamera(benchmark::State& state) {
  const Case& c = get_case(static_cast<int>(state.range(0)));
  const bool extended = state.range(1) != 0;
  state.SetLabel(std::string(case_name(static_cast<int>(state.range(0)))) +
                 (extended ? " +stdDeviations" : ""));
  double rms = 0;
  for (auto _ : state)
    benchmark::DoNotOptimize(rms = opencv_rms(c, extended));
  state.counters["rms_px"] = rms;
}
// Plain calibrateCamera on the synthetic set (~22 s a call) is timed by the paired benchmark only.
BENCHMARK(BM_CvCalibrateCamera)
    ->Args({kOpenCvSet, 0})
    ->Args({kOpenCvSet, 1})
    ->Args({kSynthetic, 1})
    ->Unit(benchmark::kMillisecond);

double thread_cpu_seconds() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

/// Both libraries back to back in every iteration (thread CPU time each), so a load change on
/// the shared machine hits both alike: the ratio is the figure to quote. Each function returns
/// its RMS (px).
void run_pair(benchmark::State& state, const std::function<double()>& storetrack,
              const std::function<double()>& opencv) {
  double ours_s = 0, theirs_s = 0, ours_rms = 0, theirs_rms = 0;
  for (auto _ : state) {
    const double t0 = thread_cpu_seconds();
    ours_rms = storetrack();
    const double t1 = thread_cpu_seconds();
    theirs_rms = opencv();
    const double t2 = thread_cpu_seconds();
    ours_s += t1 - t0;
    theirs_s += t2 - t1;
  }
  const auto n = static_cast<double>(state.iterations());
  state.counters["storetrack_ms"] = 1e3 * ours_s / n;
  state.counters["opencv_ms"] = 1e3 * theirs_s / n;
  state.counters["opencv_over_storetrack"] = theirs_s / ours_s;
  state.counters["rms_storetrack_px"] = ours_rms;
  state.counters["rms_opencv_px"] = theirs_rms;
  state.counters["rms_storetrack_minus_opencv_px"] = ours_rms - theirs_rms;
  // Same minimum: the RMS agree to 1e-4 relative (OpenCV's float inputs, stopping criteria).
  if (std::abs(ours_rms - theirs_rms) > 1e-4 * theirs_rms)
    state.SkipWithError("the two calibrations did not reach the same RMS");
}

/// OpenCV without its standard deviations; storetrack with its covariance (it always computes
/// it).
void BM_IntrinsicStoretrackVsOpenCv(benchmark::State& state) {
  const Case& c = get_case(static_cast<int>(state.range(0)));
  state.SetLabel(case_name(static_cast<int>(state.range(0))));
  run_pair(
      state, [&c] { return storetrack_rms(c); }, [&c] { return opencv_rms(c, false); });
}
BENCHMARK(BM_IntrinsicStoretrackVsOpenCv)
    ->Arg(kOpenCvSet)
    ->Arg(kSynthetic)
    ->Unit(benchmark::kMillisecond);

/// One camera of the fisheye set in both libraries' input forms (OpenCV's in double, as its
/// published result was computed).
struct FisheyeCase {
  calib::ObservationSet set;
  calib::IntrinsicOptions options;
  std::vector<std::vector<cv::Point3d>> object_points;  // per view, frame order
  std::vector<std::vector<cv::Point2d>> image_points;
  cv::Size image_size;
};

FisheyeCase fisheye_case(int camera) {
  const std::string set = std::string(STORETRACK_TEST_DATA_DIR) + "/opencv_fisheye_stereo_jy";
  FisheyeCase c;
  c.set = calib::read_observations_csv(set + (camera == 0 ? "/left.csv" : "/right.csv"));
  c.options.lens_model = camera::LensModel::kKannalaBrandt;
  c.options.outlier_false_alarm = 0;                         // cv::fisheye keeps every point
  c.options.board_deflection = calib::BoardDeflection::off;  // and fits a flat board
  std::map<int, size_t> view_of_frame;                       // std::map: views in frame order
  for (const calib::Observation& o : c.set.observations)
    view_of_frame.emplace(o.frame, 0);
  size_t next = 0;
  for (auto& [frame, view] : view_of_frame)
    view = next++;
  c.object_points.resize(next);
  c.image_points.resize(next);
  for (const calib::Observation& o : c.set.observations) {
    const size_t view = view_of_frame.at(o.frame);
    c.object_points[view].emplace_back(o.p_board.x(), o.p_board.y(), o.p_board.z());
    c.image_points[view].emplace_back(o.pixel.x(), o.pixel.y());
  }
  const calib::ImageSize size = c.set.image_sizes.at(camera);
  c.image_size = cv::Size(size.width, size.height);
  return c;
}

/// cv::fisheye::calibrate as OpenCV's fisheyeTest.Calibration calls it (its published result).
double opencv_fisheye_rms(const FisheyeCase& c) {
  cv::Matx33d K;
  cv::Vec4d D;
  constexpr int flags = cv::fisheye::CALIB_RECOMPUTE_EXTRINSIC | cv::fisheye::CALIB_CHECK_COND |
                        cv::fisheye::CALIB_FIX_SKEW;
  return cv::fisheye::calibrate(c.object_points, c.image_points, c.image_size, K, D, cv::noArray(),
                                cv::noArray(), flags, cv::TermCriteria(3, 20, 1e-6));
}

/// Argument: the camera (0 left, 1 right).
void BM_FisheyeStoretrackVsOpenCv(benchmark::State& state) {
  static const FisheyeCase cases[2] = {fisheye_case(0), fisheye_case(1)};
  const int camera = static_cast<int>(state.range(0));
  const FisheyeCase& c = cases[camera];
  state.SetLabel(camera == 0 ? "fisheye_jy_left" : "fisheye_jy_right");
  run_pair(
      state, [&] { return calib::calibrate_intrinsics(c.set, camera, c.options).rms_px; },
      [&c] { return opencv_fisheye_rms(c); });
}
BENCHMARK(BM_FisheyeStoretrackVsOpenCv)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

}  // namespace

int main(int argc, char** argv) {
  cv::setNumThreads(1);  // one core each: Ceres runs with num_threads = 1
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
