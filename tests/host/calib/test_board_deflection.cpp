// Board deflection (mrcal's calobject_warp) against simulator truth: boards rendered with a known
// bow (1 mm deep at the centre of the 0.45 x 0.30 m board), fitted with the deflection on and off;
// a flat board; a surveyed non-flat board (z != 0 in the observations). Every band is the
// two-sided 99.9 % chi-square interval of a sum of N independent NEES values (N stated per test).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>

#include "storetrack/calib/intrinsic_calibration.hpp"
#include "storetrack/calib/rig_calibration.hpp"
#include "storetrack/uncertainty/statistics.hpp"
#include "synthetic_board.hpp"

namespace storetrack::calib {
namespace {

using uncertainty::chi_square_quantile;
using uncertainty::DegreesOfFreedom;
using uncertainty::Probability;

#ifdef STORETRACK_SANITIZE
constexpr int kTrials = 4;  // ~10x slower under ASan/UBSan: the band widens with the small N
#else
constexpr int kTrials = 25;
#endif
constexpr int kViews = 15;
constexpr double kSigmaPx = 0.2;
constexpr double kBowX = 0.6e-3, kBowY = 0.4e-3;  // [m]: 1 mm deep at the board's centre

/// The 9 estimated parameters (5-coefficient model, skew fixed) in the packed vector.
constexpr std::array<int, 9> kFree = {0, 1, 2, 3, 5, 6, 7, 8, 9};

ObservationSet rendered_set(const test::BoardGrid& grid, std::mt19937_64& rng) {
  const camera::CameraModel model(test::truth_camera());
  std::normal_distribution<double> noise(0, kSigmaPx);
  ObservationSet set;
  set.image_sizes[0] = {1920, 1024};
  for (int i = 0; i < kViews; ++i)
    test::add_board_view(model, test::board_pose(i, false, grid), 0, i, noise, rng, set, grid);
  return set;
}

double intrinsics_nees(const IntrinsicResult& r) {
  return test::free_intrinsics_nees(r.intrinsics, r.covariance, test::truth_camera(), kFree);
}

double deflection_nees(const IntrinsicResult& r, const Eigen::Vector2d& truth) {
  const Eigen::Vector2d e = r.board_deflection.c_m - truth;
  return e.dot(r.board_deflection.covariance.ldlt().solve(e));
}

/// Two-sided 99.9 % interval of a sum of `trials` chi-square(dim) values.
struct Band {
  double low, high;
};
Band nees_band(int dim) {
  const DegreesOfFreedom dof(dim * kTrials);
  return {chi_square_quantile(Probability(0.0005), dof),
          chi_square_quantile(Probability(0.9995), dof)};
}

/// dof s^2 / sigma^2 of the fit: chi-square(dof) when the model explains the data.
double residual_chi_square(const IntrinsicResult& r) {
  return (2 * r.points_used - r.free_parameters) * std::pow(r.residual_sigma_px / kSigmaPx, 2);
}
double residual_upper_bound(const IntrinsicResult& r) {
  return chi_square_quantile(Probability(0.9995),
                             DegreesOfFreedom(2 * r.points_used - r.free_parameters));
}

IntrinsicOptions with_deflection(BoardDeflection mode) {
  IntrinsicOptions options;
  options.board_deflection = mode;
  return options;
}

TEST(BoardDeflection, FittedBowAndIntrinsicsAgreeWithTruthAndTheFlatFitDoesNot) {
  test::BoardGrid grid;
  grid.bow_x_m = kBowX;
  grid.bow_y_m = kBowY;
  std::mt19937_64 rng(20261206);
  double warped_c = 0, warped_k = 0, flat_k = 0;
  int flat_residual_fails = 0;
  for (int t = 0; t < kTrials; ++t) {
    const ObservationSet set = rendered_set(grid, rng);
    const IntrinsicResult warped = calibrate_intrinsics(set, 0, IntrinsicOptions{});  // auto
    ASSERT_TRUE(warped.board_deflection.fitted) << warped.board_deflection.reason;
    // The fit's extent is the rendered grid's (the truth is stated over it).
    EXPECT_DOUBLE_EQ(warped.board_deflection.x_max, (grid.cols - 1) * grid.square_m);
    EXPECT_DOUBLE_EQ(warped.board_deflection.y_max, (grid.rows - 1) * grid.square_m);
    warped_c += deflection_nees(warped, {kBowX, kBowY});
    warped_k += intrinsics_nees(warped);
    EXPECT_LT(residual_chi_square(warped), residual_upper_bound(warped));
    const IntrinsicResult flat =
        calibrate_intrinsics(set, 0, with_deflection(BoardDeflection::off));
    EXPECT_FALSE(flat.board_deflection.fitted);
    flat_k += intrinsics_nees(flat);
    flat_residual_fails += residual_chi_square(flat) > residual_upper_bound(flat);
    if (t == 0)
      std::printf(
          "seed 0: c = (%.3f +- %.3f, %.3f +- %.3f) mm (truth %.1f, %.1f); fx warped "
          "%.2f +- %.2f, flat %.2f +- %.2f (truth %.2f); rms warped %.3f, flat %.3f px\n",
          1e3 * warped.board_deflection.c_m.x(),
          1e3 * std::sqrt(warped.board_deflection.covariance(0, 0)),
          1e3 * warped.board_deflection.c_m.y(),
          1e3 * std::sqrt(warped.board_deflection.covariance(1, 1)), 1e3 * kBowX, 1e3 * kBowY,
          warped.intrinsics.fx, std::sqrt(warped.covariance(0, 0)), flat.intrinsics.fx,
          std::sqrt(flat.covariance(0, 0)), test::truth_camera().fx, warped.rms_px, flat.rms_px);
  }
  const Band c_band = nees_band(2), k_band = nees_band(9);
  std::printf(
      "N = %d: sum NEES deflection %.1f in [%.1f, %.1f]; intrinsics warped %.1f, flat "
      "%.1f in [%.1f, %.1f]; flat residual above its chi-square bound in %d of %d\n",
      kTrials, warped_c, c_band.low, c_band.high, warped_k, flat_k, k_band.low, k_band.high,
      flat_residual_fails, kTrials);
  EXPECT_GT(warped_c, c_band.low);
  EXPECT_LT(warped_c, c_band.high);
  EXPECT_GT(warped_k, k_band.low);
  EXPECT_LT(warped_k, k_band.high);
  // The same data fitted flat: the intrinsics are biased far outside their stated uncertainty
  // and the residuals exceed the noise in every trial.
  EXPECT_GT(flat_k, k_band.high);
  EXPECT_EQ(flat_residual_fails, kTrials);
}

TEST(BoardDeflection, FlatBoardFitsABowlConsistentWithZeroAndKeepsTheIntrinsics) {
  const test::BoardGrid grid;  // flat
  std::mt19937_64 rng(20261207);
  double c_sum = 0, k_sum = 0, worst_sigma = 0, worst_z2 = 0;
  for (int t = 0; t < kTrials; ++t) {
    const ObservationSet set = rendered_set(grid, rng);
    const IntrinsicResult warped = calibrate_intrinsics(set, 0, IntrinsicOptions{});
    ASSERT_TRUE(warped.board_deflection.fitted) << warped.board_deflection.reason;
    c_sum += deflection_nees(warped, Eigen::Vector2d::Zero());
    k_sum += intrinsics_nees(warped);
    // The two fits are nested: on a flat board the shift of each parameter is normal with
    // variance C_warped - C_flat (Hausman: the flat fit is efficient, the warped one consistent).
    const IntrinsicResult flat =
        calibrate_intrinsics(set, 0, with_deflection(BoardDeflection::off));
    const camera::IntrinsicVector shift =
        camera::pack(warped.intrinsics) - camera::pack(flat.intrinsics);
    for (int j : kFree) {
      worst_sigma = std::max(worst_sigma, std::abs(shift[j]) / std::sqrt(warped.covariance(j, j)));
      // Each fit scales its covariance by its own residual variance: compare at the true one.
      // A parameter the bowl hardly touches has a difference at rounding level (the two
      // Jacobians are taken at slightly different estimates): floored at 1 % of its variance.
      const double warped_variance =
          kSigmaPx * kSigmaPx * warped.covariance(j, j) / std::pow(warped.residual_sigma_px, 2);
      const double flat_variance =
          kSigmaPx * kSigmaPx * flat.covariance(j, j) / std::pow(flat.residual_sigma_px, 2);
      const double variance = std::max(warped_variance - flat_variance, 0.01 * warped_variance);
      worst_z2 = std::max(worst_z2, shift[j] * shift[j] / variance);
    }
  }
  const Band c_band = nees_band(2), k_band = nees_band(9);
  // 9 N squared normal shifts: their largest stays below the chi-square(1) quantile at
  // 1 - 0.001 / (9 N) with probability 99.9 % (Bonferroni).
  const double z2_bound =
      chi_square_quantile(Probability(1 - 0.001 / (9.0 * kTrials)), DegreesOfFreedom(1));
  std::printf(
      "flat board, N = %d: sum NEES deflection (truth 0) %.1f in [%.1f, %.1f], intrinsics "
      "%.1f in [%.1f, %.1f]; largest shift from the flat fit %.2f of its own sigma, "
      "largest squared shift over its variance %.1f < %.1f\n",
      kTrials, c_sum, c_band.low, c_band.high, k_sum, k_band.low, k_band.high, worst_sigma,
      worst_z2, z2_bound);
  EXPECT_GT(c_sum, c_band.low);
  EXPECT_LT(c_sum, c_band.high);
  EXPECT_GT(k_sum, k_band.low);
  EXPECT_LT(k_sum, k_band.high);
  EXPECT_LT(worst_z2, z2_bound);
}

TEST(BoardDeflection, SurveyedNonPlanarBoardIsAcceptedAndFitsToTruth) {
  // A target with a surveyed relief of +-3 mm (not a bowl): the observations carry the true z.
  test::BoardGrid surveyed;
  surveyed.relief_m = 3e-3;
  surveyed.surveyed = true;
  test::BoardGrid nominal = surveyed;  // the same target given as flat
  nominal.surveyed = false;
  std::mt19937_64 rng(20261208);
  double c_sum = 0, k_sum = 0;
  int nominal_fails = 0;
  for (int t = 0; t < kTrials; ++t) {
    std::mt19937_64 twin = rng;  // the same noise for both renderings
    const ObservationSet set = rendered_set(surveyed, rng);
    const IntrinsicResult r = calibrate_intrinsics(set, 0, IntrinsicOptions{});
    ASSERT_TRUE(r.board_deflection.fitted) << r.board_deflection.reason;
    c_sum += deflection_nees(r, Eigen::Vector2d::Zero());  // no bow on top of the survey
    k_sum += intrinsics_nees(r);
    EXPECT_LT(residual_chi_square(r), residual_upper_bound(r));
    const IntrinsicResult flat =
        calibrate_intrinsics(rendered_set(nominal, twin), 0, IntrinsicOptions{});
    nominal_fails += residual_chi_square(flat) > residual_upper_bound(flat);
  }
  const Band c_band = nees_band(2), k_band = nees_band(9);
  std::printf(
      "surveyed board (+-3 mm relief), N = %d: sum NEES deflection (truth 0) %.1f in "
      "[%.1f, %.1f], intrinsics %.1f in [%.1f, %.1f]; given as flat: residuals above "
      "the noise in %d of %d\n",
      kTrials, c_sum, c_band.low, c_band.high, k_sum, k_band.low, k_band.high, nominal_fails,
      kTrials);
  EXPECT_GT(c_sum, c_band.low);
  EXPECT_LT(c_sum, c_band.high);
  EXPECT_GT(k_sum, k_band.low);
  EXPECT_LT(k_sum, k_band.high);
  EXPECT_EQ(nominal_fails, kTrials);  // the survey's z is what the fit uses
}

TEST(BoardDeflection, BoardsThatCannotBeUsedAreRefusedWithTheReason) {
  std::mt19937_64 rng(20261209);
  test::BoardGrid relief;  // a "board" 0.1 m deep: the homography start cannot hold
  relief.relief_m = 0.1;
  relief.surveyed = true;
  try {
    calibrate_intrinsics(rendered_set(relief, rng), 0, IntrinsicOptions{});
    ADD_FAILURE() << "a 0.1 m relief was accepted";
  } catch (const CalibrationError& e) {
    EXPECT_NE(std::string(e.what()).find("more than 10 % of the board's larger side"),
              std::string::npos)
        << e.what();
  }
  test::BoardGrid two_columns;  // a parabola along x needs 3 distinct x
  two_columns.cols = 2;
  const ObservationSet set = rendered_set(two_columns, rng);
  const IntrinsicResult r = calibrate_intrinsics(set, 0, IntrinsicOptions{});
  EXPECT_FALSE(r.board_deflection.fitted);
  EXPECT_NE(r.board_deflection.reason.find("2 distinct x"), std::string::npos)
      << r.board_deflection.reason;
  try {
    calibrate_intrinsics(set, 0, with_deflection(BoardDeflection::on));
    ADD_FAILURE() << "--board-deflection on accepted a board of 2 columns";
  } catch (const CalibrationError& e) {
    EXPECT_NE(std::string(e.what()).find("the board deflection cannot be fitted: the board has 2 "
                                         "distinct x"),
              std::string::npos)
        << e.what();
  }
}

TEST(BoardDeflection, RigFitsOneBowForEveryCameraAgreeingWithTruth) {
  // Two cameras 0.3 m apart (camera 1 turned 6 degrees towards the boards), the same bowed board.
  constexpr int kRigTrials = kTrials < 10 ? kTrials : 10;
  test::BoardGrid grid;
  grid.bow_x_m = kBowX;
  grid.bow_y_m = kBowY;
  const camera::CameraModel model(test::truth_camera());
  const geometry::Transform T_1_r =
      geometry::make_transform(geometry::Vec3(0, -0.1, 0), geometry::Vec3(0.3, 0, 0)).inverse();
  std::mt19937_64 rng(20261210);
  double c_sum = 0;
  for (int t = 0; t < kRigTrials; ++t) {
    std::normal_distribution<double> noise(0, kSigmaPx);
    ObservationSet set;
    set.image_sizes[0] = set.image_sizes[1] = {1920, 1024};
    for (int i = 0; i < kViews; ++i) {
      const geometry::Transform T_r_b = test::board_pose(i, false, grid);
      test::add_board_view(model, T_r_b, 0, i, noise, rng, set, grid);
      test::add_board_view(model, T_1_r * T_r_b, 1, i, noise, rng, set, grid);
    }
    const RigResult r = calibrate_rig(set, RigOptions{});
    ASSERT_TRUE(r.board_deflection.fitted) << r.board_deflection.reason;
    const Eigen::Vector2d e = r.board_deflection.c_m - Eigen::Vector2d(kBowX, kBowY);
    c_sum += e.dot(r.board_deflection.covariance.ldlt().solve(e));
    const int dof = 2 * r.points_used - r.free_parameters;
    EXPECT_LT(dof * std::pow(r.residual_sigma_px / kSigmaPx, 2),
              chi_square_quantile(Probability(0.9995), DegreesOfFreedom(dof)));
  }
  const DegreesOfFreedom dof(2 * kRigTrials);
  const double low = chi_square_quantile(Probability(0.0005), dof),
               high = chi_square_quantile(Probability(0.9995), dof);
  std::printf("rig, N = %d: sum NEES deflection %.1f in [%.1f, %.1f]\n", kRigTrials, c_sum, low,
              high);
  EXPECT_GT(c_sum, low);
  EXPECT_LT(c_sum, high);
}

}  // namespace
}  // namespace storetrack::calib
