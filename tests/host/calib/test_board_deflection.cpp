// Board deflection (mrcal's calobject_warp) against simulator truth: boards rendered with a known
// bow (1 mm deep at the centre of the 0.45 x 0.30 m board), fitted with the deflection on and off;
// a flat board; a surveyed non-flat board (z != 0 in the observations). Every band is the
// two-sided 99.9 % chi-square interval of a sum of N independent NEES values (N stated per test).
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <random>

#include "storetrack/calib/intrinsic_calibration.hpp"
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
  const camera::IntrinsicVector e = camera::pack(r.intrinsics) - camera::pack(test::truth_camera());
  Eigen::Matrix<double, 9, 1> e9;
  Eigen::Matrix<double, 9, 9> C9;
  for (int a = 0; a < 9; ++a) {
    e9[a] = e[kFree[a]];
    for (int b = 0; b < 9; ++b)
      C9(a, b) = r.covariance(kFree[a], kFree[b]);
  }
  return e9.dot(C9.ldlt().solve(e9));
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

}  // namespace
}  // namespace storetrack::calib
