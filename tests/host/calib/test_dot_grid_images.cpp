// Real photographs: DICe's stereo donut-dot target (tests/data/dice_stereo_dot_target, BSD-3,
// SOURCE.txt): a printed black-dot grid larger than the field of view, indexed from its three
// ring dots, measured with the unit's centroider. Done when (issue 9): both cameras detected
// and the stereo rig calibrates with RMS <= 0.75 px (DICe's own acceptance for these pairs).
#include <gtest/gtest.h>

#include <cstdio>

#include <opencv2/imgcodecs.hpp>

#include "dot_grid_rendering.hpp"
#include "storetrack/calib/dot_grid_detection.hpp"
#include "storetrack/calib/rig_calibration.hpp"

namespace storetrack::calib {
namespace {

const std::string kSet = std::string(STORETRACK_TEST_DATA_DIR) + "/dice_stereo_dot_target/images/";
constexpr int kPairs = 13;            // DICe's test: pairs 1..13
constexpr double kDiceRmsPx = 0.75;   // DICe_TestCalibration.cpp, "stereo donut dots"
constexpr double kSpacingM = 0.0035;  // 3.5 DICe units, taken as mm (unit not stated)

// stereo_marker_dots_input.xml
DotGridSpec dice_target() {
  DotGridSpec spec;
  spec.kind = DotBoardKind::kRingDots;
  spec.cols = 10, spec.rows = 8, spec.spacing_m = kSpacingM, spec.dark_dots = true;
  spec.origin_col = 2, spec.origin_row = 2, spec.origin_to_x_marker = 6,
  spec.origin_to_y_marker = 4;
  return spec;
}

/// The 26 JPEGs decoded once for all tests (2448 x 2048 each).
const std::vector<cv::Mat>& decoded(int side) {
  static const std::array<std::vector<cv::Mat>, 2> images = [] {
    std::array<std::vector<cv::Mat>, 2> all;
    for (int s = 0; s < 2; ++s)
      for (int i = 1; i <= kPairs; ++i) {
        char name[64];
        std::snprintf(name, sizeof name, "CalB-sys2-%04d_%d.jpeg", i, s);
        all[static_cast<size_t>(s)].push_back(cv::imread(kSet + name, cv::IMREAD_GRAYSCALE));
      }
    return all;
  }();
  return images[static_cast<size_t>(side)];
}

const DotDetectionResult& detected(int side) {
  static const std::array<DotDetectionResult, 2> results = [] {
    std::array<DotDetectionResult, 2> r;
    for (int s = 0; s < 2; ++s) {
      std::vector<GrayImageView> views;
      for (size_t i = 0; i < decoded(s).size(); ++i) {
        const cv::Mat& m = decoded(s)[i];
        char name[64];
        std::snprintf(name, sizeof name, "CalB-sys2-%04zu_%d.jpeg", i + 1, s);
        views.push_back({name, m.data, m.cols, m.rows, static_cast<int>(m.step)});
      }
      r[static_cast<size_t>(s)] = detect_dot_grids(views, dice_target(), {}, s);
    }
    return r;
  }();
  return results[static_cast<size_t>(side)];
}

TEST(DotGridImages, BothCamerasDetectedWithMarkersWhereExpected) {
  // Ring-dot hole centres of pair 1 measured independently (scipy: threshold at 0.6 x the
  // median, fill holes, centre of mass of each hole; to ~2 px): origin, x marker, y marker.
  const std::array<std::array<Eigen::Vector2d, 3>, 2> pair1 = {
      {{{{462, 1361}, {1615, 1403}, {494, 639}}}, {{{461, 1342}, {1598, 1383}, {478, 649}}}}};
  for (int side = 0; side < 2; ++side) {
    ASSERT_EQ(decoded(side).size(), static_cast<size_t>(kPairs));
    const DotDetectionResult& r = detected(side);
    for (const auto& rejected : r.rejected)
      ADD_FAILURE() << rejected.path << ": " << rejected.reason;
    EXPECT_EQ(r.images_used, kPairs);
    ASSERT_EQ(r.markers.size(), static_cast<size_t>(kPairs));
    for (int k = 0; k < 3; ++k)
      EXPECT_LT((r.markers[0].second[static_cast<size_t>(k)] - pair1[side][k]).norm(), 5.0)
          << "camera " << side << " marker " << k;
    std::map<std::string, int> reasons;
    for (const auto& d : r.rejected_dots)
      ++reasons[d.reason.substr(0, d.reason.find(" ("))];
    std::printf("camera %d: %zu dots indexed in %d images; not used:", side,
                r.set.observations.size(), r.images_used);
    for (const auto& [reason, n] : reasons)
      std::printf(" %d %s;", n, reason.c_str());
    std::printf("\n");
    std::vector<double> sigmas;
    for (const auto& o : r.set.observations) {
      ASSERT_TRUE(o.sigma_px.has_value());
      sigmas.push_back(*o.sigma_px);
    }
    std::sort(sigmas.begin(), sigmas.end());
    std::printf("camera %d: centroider sigma min %.4f median %.4f max %.4f px\n", side,
                sigmas.front(), sigmas[sigmas.size() / 2], sigmas.back());
    // A sanity bound, not a tolerance: a ~94 px dot's photon-noise sigma is a small fraction
    // of a pixel (its ~300 edge pixels each carry the position).
    EXPECT_GT(sigmas.front(), 0);
    EXPECT_LT(sigmas.back(), 0.25);
  }
}

// Indexing: in every image the indexed dots must form the grid: a homography board -> image
// fitted to them leaves residuals far below one spacing (a dot off by one node is ~230 px
// away; lens distortion over the view leaves a few px), and the spacing measured between
// neighbouring indexed dots is smooth (no skipped or doubled node: ratio 0.8-1.25).
TEST(DotGridImages, EveryImageIndexedAsAGrid) {
  for (int side = 0; side < 2; ++side) {
    const DotDetectionResult& r = detected(side);
    std::map<int, std::vector<const Observation*>> frames;
    for (const auto& o : r.set.observations)
      frames[o.frame].push_back(&o);
    for (const auto& [frame, points] : frames) {
      std::vector<cv::Point2f> board, image;
      std::map<int, Eigen::Vector2d> by_id;
      for (const Observation* o : points) {
        board.emplace_back(static_cast<float>(o->p_board.x()), static_cast<float>(o->p_board.y()));
        image.emplace_back(static_cast<float>(o->pixel.x()), static_cast<float>(o->pixel.y()));
        by_id[o->point_id] = o->pixel;
      }
      EXPECT_GE(points.size(), 40u) << "camera " << side << " frame " << frame;
      std::vector<double> steps;
      for (const auto& [id, p] : by_id)
        if (id % 10 < 9 && by_id.count(id + 1)) steps.push_back((by_id[id + 1] - p).norm());
      std::sort(steps.begin(), steps.end());
      const double median = steps[steps.size() / 2];
      EXPECT_GT(steps.front(), 0.8 * median) << "camera " << side << " frame " << frame;
      EXPECT_LT(steps.back(), 1.25 * median) << "camera " << side << " frame " << frame;
    }
  }
}

TEST(DotGridImages, StereoRigCalibratesWithinDicesAcceptance) {
  ObservationSet set = detected(0).set;
  const ObservationSet& right = detected(1).set;
  set.observations.insert(set.observations.end(), right.observations.begin(),
                          right.observations.end());
  set.image_sizes[1] = right.image_sizes.at(1);
  RigOptions options;
  options.intrinsic.outlier_false_alarm = 0;  // every indexed dot, as DICe
  const RigResult rig = calibrate_rig(set, options);
  ASSERT_EQ(rig.cameras.size(), 2u);
  const auto& left_camera = rig.cameras[0];
  const auto& right_camera = rig.cameras[1];
  std::printf(
      "DICe dot target: RMS left %.4f px right %.4f px all %.4f px (DICe accepts <= %.2f), "
      "fx %.1f / %.1f px, baseline %.3f +/- %.3f mm, %d points, residual sigma %.4f px\n",
      left_camera.rms_px, right_camera.rms_px, rig.rms_px, kDiceRmsPx, left_camera.intrinsics.fx,
      right_camera.intrinsics.fx, 1e3 * right_camera.baseline_m,
      1e3 * right_camera.baseline_sigma_m, rig.points_used, rig.residual_sigma_px);
  EXPECT_LE(rig.rms_px, kDiceRmsPx);
  EXPECT_LE(left_camera.rms_px, kDiceRmsPx);
  EXPECT_LE(right_camera.rms_px, kDiceRmsPx);
  EXPECT_EQ(right_camera.common_views_with_reference, kPairs);

  // Perspective bias of the dot centroid (imaged circle's centre - projected centre) through
  // the fitted poses and pinhole part of the cameras; dot diameter 0.416 spacings (measured on
  // pair 1: median dot area 6969 px, spacing 226.4 px).
  const double radius = 0.5 * 0.416 * kSpacingM;
  double max_bias = 0, sum_sq = 0;
  int n = 0;
  for (size_t c = 0; c < 2; ++c) {
    const camera::Intrinsics& in = rig.cameras[c].intrinsics;
    Eigen::Matrix3d K;
    K << in.fx, 0, in.cx, 0, in.fy, in.cy, 0, 0, 1;
    for (const auto& o : set.observations) {
      if (o.camera != static_cast<int>(c)) continue;
      const size_t f = static_cast<size_t>(
          std::find(rig.frames.begin(), rig.frames.end(), o.frame) - rig.frames.begin());
      const geometry::Transform T_c_b = rig.cameras[c].T_c_r * rig.T_r_b[f];
      Eigen::Matrix3d M;
      M << T_c_b.linear().col(0), T_c_b.linear().col(1), T_c_b.translation();
      const Eigen::Matrix3d H = K * M;
      const Eigen::Vector2d centre = o.p_board.head<2>();
      const double bias =
          (test::imaged_circle_centre(H, centre, radius) - (H * centre.homogeneous()).hnormalized())
              .norm();
      max_bias = std::max(max_bias, bias);
      sum_sq += bias * bias;
      ++n;
    }
  }
  std::printf("perspective bias of the dot centroids: rms %.4f px, max %.4f px over %d dots\n",
              std::sqrt(sum_sq / n), max_bias, n);
  // Not corrected (docs/calibration.md, "Perspective bias"): it stays below a fifth of the
  // acceptance. Closed form for a dot of radius R px on the axis, plane tilted by theta:
  // (R^2 / f) sin(theta) cos(theta) <= 47^2 / 12500 / 2 = 0.09 px here.
  EXPECT_LT(max_bias, 0.2 * kDiceRmsPx);
}

}  // namespace
}  // namespace storetrack::calib
