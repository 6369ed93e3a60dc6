// Real wide-angle data: OpenCV's fisheye stereo set "calib-3_stereo_from_JY" (two 1280 x 800
// fisheye cameras, 34 views of an 8 x 6 corner board; tests/data/opencv_fisheye_stereo_jy,
// README.md). The project's Kannala-Brandt calibration against (a) the values OpenCV publishes
// in modules/calib3d/test/test_fisheye.cpp for this data and (b) cv::fisheye run here on the
// same points. Tolerances come from the project's own stated covariance: the difference to the
// published vector must lie inside the chi-square 99.9 % quantile of its dimension; the RMS may
// not exceed OpenCV's on the same points (same model and cost: a smaller minimum or the same).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iterator>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "storetrack/calib/intrinsic_calibration.hpp"
#include "storetrack/calib/observations.hpp"
#include "storetrack/calib/rig_calibration.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::calib {
namespace {

const std::string kSet = std::string(STORETRACK_TEST_DATA_DIR) + "/opencv_fisheye_stereo_jy";
constexpr int kViews = 34, kCorners = 48;
const cv::Size kImageSize(1280, 800);

// OpenCV modules/calib3d/test/test_fisheye.cpp (README.md: commit and test names).
// fisheyeTest.Calibration (left camera alone): fx, fy, cx, cy, k1..k4.
constexpr double kPublishedLeft[8] = {
    558.478087865323,    560.506767351568,     620.458515360843,    381.939424848348,
    -0.0014613319981768, -0.00329861110580401, 0.00605760088590183, -0.00374209380722371};
// fisheyeTest.EstimateUncertainties: the RMS of that solution (per point, sqrt(SSR / N)).
constexpr double kPublishedLeftRms = 0.263782587133546;
// fisheyeTest.stereoCalibrate: both cameras' intrinsics and R, T (camera 0 -> camera 1).
constexpr double kPublishedStereoLeft[8] = {
    561.195925927249,      562.849402029712,     621.282400272412,    380.555455380889,
    -7.44253716539556e-05, -0.00702662033932424, 0.00737569823650885, -0.00342230256441771};
constexpr double kPublishedStereoRight[8] = {
    560.395452535348,    561.90171021422,    678.971652040359,    380.401340535339,
    -0.0130785435677431, 0.0284434505383497, -0.0360333869900506, 0.0144724062347222};
constexpr double kPublishedR[9] = {
    0.9975587205950972,    0.06953016383322372,   0.006492709911733523,
    -0.06956823121068059,  0.9975601387249519,    0.005833595226966235,
    -0.006071257768382089, -0.006271040135405457, 0.9999619062167968};
constexpr double kPublishedT[3] = {-0.099402724724121, 0.00270812139265413, 0.00129330292472699};
// Both solvers minimise the same sum of squares; the slack is convergence (OpenCV stops after
// 20 (mono) or 12 (stereo) iterations or a 1e-6 relative step).
constexpr double kRmsSlackPx = 1e-4;

/// The packed-intrinsic indices of fx, fy, cx, cy, k1..k4 (calibration-file order; skew fixed).
constexpr int kFreeIntrinsics[8] = {0, 1, 2, 3, 5, 6, 7, 8};

ObservationSet both_cameras() {
  ObservationSet set = read_observations_csv(kSet + "/left.csv");
  const ObservationSet right = read_observations_csv(kSet + "/right.csv");
  set.observations.insert(set.observations.end(), right.observations.begin(),
                          right.observations.end());
  set.image_sizes[1] = right.image_sizes.at(1);
  return set;
}

/// One camera's points in cv::fisheye's layout, views in frame order.
struct OpenCvPoints {
  std::vector<std::vector<cv::Point3d>> board;
  std::vector<std::vector<cv::Point2d>> image;
};

OpenCvPoints opencv_points(const ObservationSet& set, int camera) {
  OpenCvPoints p;
  p.board.resize(kViews);
  p.image.resize(kViews);
  for (const Observation& o : set.observations) {
    if (o.camera != camera) continue;
    p.board[o.frame].emplace_back(o.p_board.x(), o.p_board.y(), o.p_board.z());
    p.image[o.frame].emplace_back(o.pixel.x(), o.pixel.y());
  }
  return p;
}

constexpr int kOpenCvFlags = cv::fisheye::CALIB_RECOMPUTE_EXTRINSIC |
                             cv::fisheye::CALIB_CHECK_COND | cv::fisheye::CALIB_FIX_SKEW;

struct OpenCvMono {
  double values[8] = {};
  double rms_px = 0;
};

/// cv::fisheye::calibrate exactly as fisheyeTest.Calibration calls it.
OpenCvMono opencv_calibrate(const OpenCvPoints& p) {
  cv::Matx33d K;
  cv::Vec4d D;
  OpenCvMono r;
  r.rms_px = cv::fisheye::calibrate(p.board, p.image, kImageSize, K, D, cv::noArray(),
                                    cv::noArray(), kOpenCvFlags, cv::TermCriteria(3, 20, 1e-6));
  const double v[8] = {K(0, 0), K(1, 1), K(0, 2), K(1, 2), D[0], D[1], D[2], D[3]};
  std::copy(v, v + 8, r.values);
  return r;
}

/// d^T C^-1 d over the free parameters; -1 when C is not positive definite.
double chi_square(const Eigen::VectorXd& d, const Eigen::MatrixXd& C) {
  Eigen::MatrixXd C_inv;
  if (!uncertainty::inverse_spd<Eigen::Dynamic>(C, C_inv)) return -1;
  return d.dot(C_inv * d);
}

double quantile_999(int dof) {
  return uncertainty::chi_square_quantile(uncertainty::Probability(0.999),
                                          uncertainty::DegreesOfFreedom(dof));
}

/// Prints value, published value and their difference in units of the stated sigma.
void print_side_by_side(const char* what, const camera::Intrinsics& in,
                        const camera::IntrinsicCovariance& C, const double* published) {
  static const char* names[8] = {"fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"};
  const double ours[8] = {in.fx,      in.fy,      in.cx,      in.cy,
                          in.dist[0], in.dist[1], in.dist[2], in.dist[3]};
  std::printf("%s\n", what);
  for (int i = 0; i < 8; ++i) {
    const double u = std::sqrt(C(kFreeIntrinsics[i], kFreeIntrinsics[i]));
    std::printf("  %-2s project %.9g +/- %.3g  OpenCV %.9g  (diff %.2e sigma)\n", names[i], ours[i],
                u, published[i], (ours[i] - published[i]) / u);
  }
}

Eigen::VectorXd intrinsic_difference(const camera::Intrinsics& in, const double* published) {
  Eigen::VectorXd d(8);
  d << in.fx - published[0], in.fy - published[1], in.cx - published[2], in.cy - published[3],
      in.dist[0] - published[4], in.dist[1] - published[5], in.dist[2] - published[6],
      in.dist[3] - published[7];
  return d;
}

Eigen::MatrixXd free_block(const Eigen::MatrixXd& C, const std::vector<int>& index) {
  Eigen::MatrixXd B(index.size(), index.size());
  for (size_t i = 0; i < index.size(); ++i)
    for (size_t j = 0; j < index.size(); ++j)
      B(i, j) = C(index[i], index[j]);
  return B;
}

/// As OpenCV fits: every point kept, the board flat as given.
IntrinsicOptions opencv_like_options() {
  IntrinsicOptions o;
  o.lens_model = camera::LensModel::kKannalaBrandt;
  o.outlier_false_alarm = 0;
  o.board_deflection = BoardDeflection::off;
  return o;
}

TEST(FisheyeStereoJy, CsvHoldsThePublishedDataSet) {
  const ObservationSet set = both_cameras();
  ASSERT_EQ(set.observations.size(), 2u * kViews * kCorners);
  // The conversion is exact: cv::fisheye on the CSV's points reproduces the published solution
  // (OpenCV's own test asserts 1e-10; 1e-6 leaves room for another platform's arithmetic).
  const OpenCvMono left = opencv_calibrate(opencv_points(set, 0));
  for (int i = 0; i < 8; ++i)
    EXPECT_NEAR(left.values[i], kPublishedLeft[i],
                1e-6 * std::max(1.0, std::abs(kPublishedLeft[i])))
        << i;
  EXPECT_NEAR(left.rms_px, kPublishedLeftRms, 1e-9);
}

TEST(FisheyeStereoJy, IntrinsicsAgreeWithPublishedWithinStatedUncertainty) {
  const ObservationSet set = both_cameras();
  const IntrinsicResult left = calibrate_intrinsics(set, 0, opencv_like_options());
  print_side_by_side("left camera, intrinsic (OpenCV: fisheyeTest.Calibration)", left.intrinsics,
                     left.covariance, kPublishedLeft);
  const std::vector<int> free(std::begin(kFreeIntrinsics), std::end(kFreeIntrinsics));
  const double chi2 = chi_square(intrinsic_difference(left.intrinsics, kPublishedLeft),
                                 free_block(left.covariance, free));
  std::printf("  chi2 %.3g (8 dof, 99.9 %% quantile %.2f); RMS project %.6f OpenCV %.6f px\n", chi2,
              quantile_999(8), left.rms_px, kPublishedLeftRms);
  EXPECT_GE(chi2, 0);
  EXPECT_LT(chi2, quantile_999(8));
  EXPECT_LE(left.rms_px, kPublishedLeftRms + kRmsSlackPx);

  // The right camera has no published single-camera result: cv::fisheye on the same points.
  const IntrinsicResult right = calibrate_intrinsics(set, 1, opencv_like_options());
  const OpenCvMono opencv_right = opencv_calibrate(opencv_points(set, 1));
  print_side_by_side("right camera, intrinsic (cv::fisheye::calibrate here)", right.intrinsics,
                     right.covariance, opencv_right.values);
  const double chi2_right = chi_square(intrinsic_difference(right.intrinsics, opencv_right.values),
                                       free_block(right.covariance, free));
  std::printf("  chi2 %.3g; RMS project %.6f OpenCV %.6f px\n", chi2_right, right.rms_px,
              opencv_right.rms_px);
  EXPECT_GE(chi2_right, 0);
  EXPECT_LT(chi2_right, quantile_999(8));
  EXPECT_LE(right.rms_px, opencv_right.rms_px + kRmsSlackPx);
}

/// (rotation vector of R R_pub^T, t - t_pub): the pose difference to first order, as the left
/// perturbation of T_c_r the covariance is stated in.
Eigen::VectorXd pose_difference(const geometry::Transform& T_c_r) {
  Eigen::Matrix3d R_pub;
  R_pub << kPublishedR[0], kPublishedR[1], kPublishedR[2], kPublishedR[3], kPublishedR[4],
      kPublishedR[5], kPublishedR[6], kPublishedR[7], kPublishedR[8];
  const Eigen::Vector3d t_pub(kPublishedT[0], kPublishedT[1], kPublishedT[2]);
  Eigen::VectorXd d(6);
  d << geometry::rotvec_from_rotation(T_c_r.rotation() * R_pub.transpose()),
      T_c_r.translation() - t_pub;
  return d;
}

TEST(FisheyeStereoJy, RigAgreesWithPublishedStereoCalibration) {
  const ObservationSet set = both_cameras();
  RigOptions options;
  options.intrinsic = opencv_like_options();
  const RigResult rig = calibrate_rig(set, options);
  ASSERT_EQ(rig.cameras.size(), 2u);
  const RigCameraResult& left = rig.cameras[0];
  const RigCameraResult& right = rig.cameras[1];
  print_side_by_side("rig, camera 0 (OpenCV: fisheyeTest.stereoCalibrate)", left.intrinsics,
                     left.intrinsic_covariance, kPublishedStereoLeft);
  print_side_by_side("rig, camera 1", right.intrinsics, right.intrinsic_covariance,
                     kPublishedStereoRight);

  // One vector: both cameras' 8 free intrinsics and camera 1's pose, with the joint covariance.
  std::vector<int> index;
  for (int c = 0; c < 2; ++c)
    for (int i : kFreeIntrinsics)
      index.push_back(c * kRigBlockSize + i);
  for (int k = 0; k < 6; ++k)
    index.push_back(kRigBlockSize + camera::kNumIntrinsics + k);
  Eigen::VectorXd d(22);
  d << intrinsic_difference(left.intrinsics, kPublishedStereoLeft),
      intrinsic_difference(right.intrinsics, kPublishedStereoRight), pose_difference(right.T_c_r);
  const double chi2 = chi_square(d, free_block(rig.joint_covariance, index));
  const Eigen::Vector3d t = right.T_c_r.translation();
  std::printf(
      "  T [mm] project %.4f %.4f %.4f  OpenCV %.4f %.4f %.4f; rotation difference %.2e rad\n",
      1e3 * t.x(), 1e3 * t.y(), 1e3 * t.z(), 1e3 * kPublishedT[0], 1e3 * kPublishedT[1],
      1e3 * kPublishedT[2], d.segment<3>(16).norm());
  // OpenCV's stereo RMS on the same points: cv::fisheye::stereoCalibrate as the published test.
  const OpenCvPoints l = opencv_points(set, 0), r = opencv_points(set, 1);
  cv::Matx33d K1, K2, R;
  cv::Vec4d D1, D2;
  cv::Vec3d T;
  const double opencv_rms =
      cv::fisheye::stereoCalibrate(l.board, l.image, r.image, K1, D1, K2, D2, kImageSize, R, T,
                                   kOpenCvFlags, cv::TermCriteria(3, 12, 0));
  std::printf("  chi2 %.3g (22 dof, 99.9 %% quantile %.2f); RMS project %.6f OpenCV %.6f px\n",
              chi2, quantile_999(22), rig.rms_px, opencv_rms);
  EXPECT_NEAR(T[0], kPublishedT[0], 1e-9);  // the CSV is the published test's input
  EXPECT_GE(chi2, 0);
  EXPECT_LT(chi2, quantile_999(22));
  EXPECT_LE(rig.rms_px, opencv_rms + kRmsSlackPx);
  EXPECT_GE(left.rms_px, left.start_rms_px - 1e-9);  // a joint fit cannot beat a camera's own
  EXPECT_GE(right.rms_px, right.start_rms_px - 1e-9);
}

}  // namespace
}  // namespace storetrack::calib
