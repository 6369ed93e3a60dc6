// Intrinsic calibration against synthetic truth: board points projected through a known camera
// (common/camera) with Gaussian noise of known sigma. The recovered parameters must agree with
// the truth within their stated covariance (NEES, chi-square bounds), and the refusals (too few
// views, parallel boards) must name the problem.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "storetrack/calib/intrinsic_calibration.hpp"
#include "storetrack/uncertainty/statistics.hpp"
#include "synthetic_board.hpp"

namespace storetrack::calib {
namespace {

using uncertainty::chi_square_quantile;
using uncertainty::DegreesOfFreedom;
using uncertainty::Probability;

using test::board_pose;
using test::truth_camera;

ObservationSet synthetic_set(int views, double sigma_px, std::mt19937_64& rng,
                             bool parallel = false) {
  const camera::CameraModel model(truth_camera());
  std::normal_distribution<double> noise(0, sigma_px);
  ObservationSet set;
  set.image_sizes[0] = {1920, 1024};
  for (int i = 0; i < views; ++i) {
    const geometry::Transform T_c_b = board_pose(i, parallel);
    test::add_board_view(model, T_c_b, 0, i, noise, rng, set);
  }
  return set;
}

/// The 9 estimated parameters (5-coefficient model, skew fixed) in the packed vector.
constexpr std::array<int, 9> kFree = {0, 1, 2, 3, 5, 6, 7, 8, 9};

double nees(const IntrinsicResult& r) {
  return test::free_intrinsics_nees(r.intrinsics, r.covariance, truth_camera(), kFree);
}

TEST(IntrinsicSynthetic, ParametersAgreeWithTruthWithinTheirCovariance) {
  // Sum of M independent NEES values ~ chi-square(9 M) when the covariance is honest (the
  // residual variance is estimated from ~2000 degrees of freedom: a < 1 % effect on the scale).
  // Two-sided 99.9 % interval, so a correct implementation fails 1 run in 1000 seeds.
  constexpr int kTrials = 25, kViews = 15;
  constexpr double kSigma = 0.3;
  std::mt19937_64 rng(20261202);
  double nees_sum = 0;
  int rejected = 0;
  for (int t = 0; t < kTrials; ++t) {
    const ObservationSet set = synthetic_set(kViews, kSigma, rng);
    const IntrinsicResult r = calibrate_intrinsics(set, 0, IntrinsicOptions{});
    nees_sum += nees(r);
    rejected += r.points_rejected;
    // The residual sigma estimates the noise: dof s^2 / sigma^2 ~ chi-square(dof).
    const int dof = 2 * r.points_used - r.free_parameters;
    const double ratio = dof * std::pow(r.residual_sigma_px / kSigma, 2);
    EXPECT_GT(ratio, chi_square_quantile(Probability(0.0005), DegreesOfFreedom(dof)));
    EXPECT_LT(ratio, chi_square_quantile(Probability(0.9995), DegreesOfFreedom(dof)));
  }
  const DegreesOfFreedom dof(9 * kTrials);
  std::printf("mean NEES over %d calibrations: %.3f (dimension 9)\n", kTrials, nees_sum / kTrials);
  EXPECT_GT(nees_sum, chi_square_quantile(Probability(0.0005), dof));
  EXPECT_LT(nees_sum, chi_square_quantile(Probability(0.9995), dof));
  // The outlier gate's false alarm is 1 % per clean calibration: over 25 at most a few points.
  EXPECT_LE(rejected, 3);
}

TEST(IntrinsicSynthetic, GrossOutliersRejectedAndCounted) {
  std::mt19937_64 rng(7);
  ObservationSet set = synthetic_set(15, 0.3, rng);
  const std::array<size_t, 8> bad = {3, 101, 222, 350, 480, 613, 777, 901};
  for (size_t k = 0; k < bad.size(); ++k)  // 4 to 25 px: a mis-detected corner
    set.observations[bad[k]].pixel += geometry::Vec2(4.0 + 3 * k, -2.0 - k);
  const IntrinsicResult r = calibrate_intrinsics(set, 0, IntrinsicOptions{});
  EXPECT_EQ(r.points_rejected, static_cast<int>(bad.size()));
  for (size_t k : bad)
    EXPECT_TRUE(r.residuals[k].rejected) << "observation " << k;
  EXPECT_LT(nees(r), chi_square_quantile(Probability(0.999), DegreesOfFreedom(9)));
  EXPECT_LT(std::abs(r.residual_sigma_px - 0.3), 0.03);
}

TEST(IntrinsicSynthetic, StatedSigmasWeightTheFit) {
  // With the true sigma in the CSV column the weighted residual scale is ~1 (dof s^2 ~
  // chi-square(dof)), and the covariance is the same as without (it is scaled by the fit).
  std::mt19937_64 rng(11), rng_copy(11);
  ObservationSet weighted = synthetic_set(15, 0.3, rng);
  const ObservationSet plain = synthetic_set(15, 0.3, rng_copy);
  for (Observation& o : weighted.observations)
    o.sigma_px = 0.3;
  const IntrinsicResult w = calibrate_intrinsics(weighted, 0, IntrinsicOptions{});
  const IntrinsicResult u = calibrate_intrinsics(plain, 0, IntrinsicOptions{});
  const int dof = 2 * w.points_used - w.free_parameters;
  const double chi2 = dof * w.residual_sigma_px * w.residual_sigma_px;
  EXPECT_GT(chi2, chi_square_quantile(Probability(0.0005), DegreesOfFreedom(dof)));
  EXPECT_LT(chi2, chi_square_quantile(Probability(0.9995), DegreesOfFreedom(dof)));
  EXPECT_NEAR(w.intrinsics.fx, u.intrinsics.fx, 1e-6);
  EXPECT_NEAR(w.covariance(0, 0), u.covariance(0, 0), 1e-6 * u.covariance(0, 0));
}

TEST(Geometry, So3LeftJacobianMatchesFiniteDifferences) {
  // Exp(w + d) = Exp(J_l(w) d) Exp(w): compare J_l d with Log(Exp(w + d) Exp(w)^-1) / |d|.
  for (const geometry::Vec3& w :
       {geometry::Vec3(0.3, -1.2, 0.7), geometry::Vec3(1e-8, 0, 2e-8), geometry::Vec3(0, 3.0, 0)}) {
    const geometry::Mat3 J = geometry::so3_left_jacobian(w);
    for (int axis = 0; axis < 3; ++axis) {
      const double h = 1e-6;
      const geometry::Vec3 d = h * geometry::Vec3::Unit(axis);
      const geometry::Mat3 dR =
          geometry::rotation_from_rotvec(w + d) * geometry::rotation_from_rotvec(w).transpose();
      const geometry::Vec3 numeric = geometry::rotvec_from_rotation(dR) / h;
      EXPECT_LT((numeric - J.col(axis)).norm(), 1e-6) << "w " << w.transpose() << " axis " << axis;
    }
  }
}

std::string calibration_error(const ObservationSet& set) {
  try {
    calibrate_intrinsics(set, 0, IntrinsicOptions{});
  } catch (const CalibrationError& e) {
    return e.what();
  }
  return "(accepted)";
}

TEST(IntrinsicSynthetic, ViewWithTooFewPointsSkippedAndNamed) {
  std::mt19937_64 rng(5);
  ObservationSet set = synthetic_set(6, 0.3, rng);
  Observation lone = set.observations.front();
  lone.frame = 99;
  set.observations.push_back(lone);
  const IntrinsicResult r = calibrate_intrinsics(set, 0, IntrinsicOptions{});
  EXPECT_EQ(r.views.size(), 6u);
  ASSERT_EQ(r.views_skipped.size(), 1u);
  EXPECT_EQ(r.views_skipped[0].frame, 99);
  EXPECT_EQ(r.views_skipped[0].reason, "1 point, a homography needs >= 4");
}

TEST(IntrinsicSynthetic, TooFewViewsRefused) {
  std::mt19937_64 rng(1);
  EXPECT_EQ(calibration_error(synthetic_set(2, 0.3, rng)),
            "camera 0: too few usable views: 2 board poses, need at least 3");
}

TEST(IntrinsicSynthetic, ParallelBoardsRefusedAsDegenerate) {
  std::mt19937_64 rng(2);
  const std::string error = calibration_error(synthetic_set(12, 0.3, rng, /*parallel=*/true));
  std::printf("%s\n", error.c_str());
  EXPECT_NE(error.find("degenerate views"), std::string::npos) << error;
  EXPECT_NE(error.find("parallel"), std::string::npos) << error;
}

TEST(IntrinsicSynthetic, MissingImageSizeAndFarFromPlanarBoardRefused) {
  std::mt19937_64 rng(3);
  ObservationSet set = synthetic_set(5, 0.3, rng);
  set.image_sizes.clear();
  EXPECT_NE(calibration_error(set).find("image size unknown"), std::string::npos);
  try {
    calibrate_intrinsics(set, 4, IntrinsicOptions{});
    ADD_FAILURE() << "camera 4 accepted";
  } catch (const CalibrationError& e) {
    EXPECT_EQ(std::string(e.what()), "camera 4: no observations of this camera");
  }
  set = synthetic_set(5, 0.3, rng);
  // A surveyed z is used (test_board_deflection); one 0.1 m off a 0.45 m board's plane is not
  // a board the homography start can hold.
  set.observations[10].p_board.z() = 0.1;
  EXPECT_NE(calibration_error(set).find("more than 10 % of the board's larger side"),
            std::string::npos);
}

}  // namespace
}  // namespace storetrack::calib
