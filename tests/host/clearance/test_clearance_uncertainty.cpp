// The distance uncertainty (docs/clearance.md, "Uncertainty"): the Jacobian against finite
// differences of a closed form, the stated u against a Monte Carlo of the pose (sample size and
// the two-sided chi-square interval of the std ratio stated below), the coverage of the k = 2
// lower bound in its binomial band, and the feature-switch rule where the closest feature
// changes between the estimate and the truth.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>

#include "storetrack/clearance/clearance.hpp"
#include "storetrack/uncertainty/statistics.hpp"
#include "synthetic_meshes.hpp"

namespace storetrack::clearance {
namespace {

using geometry::Mat6;
using geometry::Transform;
using geometry::Vec3;
using geometry::Vec6;

constexpr double kAlphaPerSide = 0.001;
// Monte Carlo sizes. Under ASan/UBSan a tenth: the bands below are derived for the n that runs,
// so they stay exact; the single-feature bound's loss of coverage is asserted only at full size
// (its power needs the n = 3000 band, see FeatureSwitchRule...).
#ifdef STORETRACK_SANITIZE
constexpr int kPoseDraws = 400, kCoverageDraws = 300;
#else
constexpr int kPoseDraws = 4000, kCoverageDraws = 3000;
#endif
constexpr double kOneSidedCoverageK2 = 1 - kLowerBoundMiss;  // P(N(0,1) <= 2)

Body store_body(TriangleMesh m) {
  return {"store", BodyFrame::kStore, std::move(m)};
}
Body plane_body() {
  return {"plane", BodyFrame::kPylon, test::plane_patch(1, 0, 0, 3, 12)};
}

/// A pose covariance with correlations: C = A A^T, A lower triangular.
Mat6 correlated_covariance(const Vec6& sigma) {
  Mat6 A = sigma.asDiagonal();
  A(3, 1) = 0.5 * sigma(3);   // tx with ry
  A(5, 0) = 0.4 * sigma(5);   // tz with rx
  A(4, 2) = -0.3 * sigma(4);  // ty with rz
  return A * A.transpose();
}

/// Draws e ~ N(0, C).
struct PoseNoise {
  explicit PoseNoise(const Mat6& C, std::uint64_t seed) : L(C.llt().matrixL()), rng(seed) {}
  Vec6 draw() {
    Vec6 z;
    for (int i = 0; i < 6; ++i)
      z(i) = normal(rng);
    return L * z;
  }
  Mat6 L;
  std::mt19937_64 rng;
  std::normal_distribution<double> normal;
};

TEST(DistanceJacobian, MatchesFiniteDifferencesOfASpherePlaneClosedForm) {
  // Sphere of radius rho about q_c (frame s) above the plane z = 0 of p (z down):
  // d(T) = -(R q_c + t).z - rho; its lowest point p = R q_c + t + rho e_z, n = -e_z.
  const Vec3 q_c(1.2, 0.3, 0.1);
  const double rho = 0.15;
  const Transform T = geometry::make_transform({0.02, -0.03, 0.1}, {0.1, 0.05, -0.6});
  const auto d = [&](const Transform& Tx) { return -(Tx * q_c).z() - rho; };
  Vec6 numeric;
  const double h = 1e-6;
  for (int k = 0; k < 6; ++k) {
    const Vec6 step = Vec6::Unit(k) * h;
    numeric(k) =
        (d(geometry::perturb_left(T, step)) - d(geometry::perturb_left(T, -step))) / (2 * h);
  }
  const Vec3 p = T * q_c + rho * Vec3::UnitZ();
  const Vec6 J = distance_jacobian(p, T.translation(), -Vec3::UnitZ());
  EXPECT_LT((J - numeric).norm(), 1e-8) << J.transpose() << "\n" << numeric.transpose();
}

// Monte Carlo: N poses drawn from the covariance about T0, the spread of their distances
// against the stated u at T0. For Gaussian d, (N - 1) s^2 / u^2 ~ chi-square(N - 1): the ratio
// s / u lies in [sqrt(q(0.001) / (N - 1)), sqrt(q(0.999) / (N - 1))] (two-sided, 0.1 % per
// side): N = 4000 gives about [0.966, 1.035]. The mesh (a UV sphere, 48 x 96) adds at most its
// sagitta (< 0.2 mm here) to each distance, a variance < (0.06 mm)^2 against u^2 ~ (4 mm)^2.
TEST(ClearanceUncertainty, StatedUMatchesMonteCarloOfThePose) {
  const Vec3 q_c(1.2, 0.3, 0.1);
  ClearanceModel model({store_body(test::uv_sphere(q_c, 0.15, 48, 96)), plane_body()});
  const Transform T0 = geometry::make_transform({0.02, -0.03, 0.1}, {0.1, 0.05, -0.6});
  Vec6 sigma;
  sigma << 3e-3, 2e-3, 4e-3, 2e-3, 1.5e-3, 2.5e-3;
  const Mat6 C = correlated_covariance(sigma);
  const PartClearance nominal = model.evaluate(T0, C).at(0);
  ASSERT_NEAR(nominal.distance_m, 0.6 - 0.15 - 0.1 * 1.0, 0.1);  // sanity of the set-up
  const int N = kPoseDraws;
  PoseNoise noise(C, 27);
  double sum = 0, sum2 = 0;
  for (int i = 0; i < N; ++i) {
    const double d = model.evaluate(geometry::perturb_left(T0, noise.draw()), C).at(0).distance_m;
    sum += d;
    sum2 += d * d;
  }
  const double mean = sum / N;
  const double s = std::sqrt((sum2 - N * mean * mean) / (N - 1));
  const uncertainty::DegreesOfFreedom dof(N - 1);
  const double lo = std::sqrt(
      uncertainty::chi_square_quantile(uncertainty::Probability(kAlphaPerSide), dof) / (N - 1));
  const double hi = std::sqrt(
      uncertainty::chi_square_quantile(uncertainty::Probability(1 - kAlphaPerSide), dof) / (N - 1));
  std::printf("u %.4f mm, Monte Carlo s %.4f mm, ratio %.4f in [%.4f, %.4f]\n",
              1e3 * nominal.u_distance_m, 1e3 * s, s / nominal.u_distance_m, lo, hi);
  EXPECT_GT(s / nominal.u_distance_m, lo);
  EXPECT_LT(s / nominal.u_distance_m, hi);
  // The mean: within 3.29 u / sqrt(N) (0.1 % per side) plus the mesh sagitta.
  EXPECT_NEAR(mean, nominal.distance_m, 3.29 * nominal.u_distance_m / std::sqrt(N) + 2e-4);
}

/// Coverage run: the truth fixed, the estimate drawn about it; counts truth >= bound.
struct Coverage {
  int n = 0, rule = 0, single = 0;
  double mean_extra_margin_m = 0;  // mean (single bound - rule bound)
};

Coverage run_coverage(ClearanceModel& model, const Transform& T_true, const Mat6& C, int n,
                      std::uint64_t seed) {
  const double d_true = model.evaluate(T_true, C).at(0).distance_m;
  PoseNoise noise(C, seed);
  Coverage c;
  c.n = n;
  for (int i = 0; i < n; ++i) {
    const PartClearance r = model.evaluate(geometry::perturb_left(T_true, noise.draw()), C).at(0);
    const double single = r.distance_m - kCoverageFactor * r.u_distance_m;
    c.rule += d_true >= r.lower_bound_m;
    c.single += d_true >= single;
    c.mean_extra_margin_m += (single - r.lower_bound_m) / n;
  }
  return c;
}

// One feature (a box corner 5 cm nearer than any other): the count of truths above the k = 2
// lower bound is Binomial(n, Phi(2)) to first order; n = 3000, band at 0.1 % per side.
TEST(ClearanceUncertainty, LowerBoundCoverageOfOneFeatureIsInItsBinomialBand) {
  const TriangleMesh tilted = test::posed(test::box({0.5, 0, 0}, {0.5, 0.2, 0.2}),
                                          geometry::make_transform({0.3, 0.4, 0}, {0, 0, 0}));
  ClearanceModel model({store_body(tilted), plane_body()});
  const Transform T_true = geometry::make_transform({0, 0, 0}, {0.2, 0, -0.8});
  Vec6 sigma;
  sigma << 3e-3, 3e-3, 3e-3, 2e-3, 2e-3, 2e-3;
  const Mat6 C = correlated_covariance(sigma);
  const int n = kCoverageDraws;
  const uncertainty::CountInterval band =
      uncertainty::binomial_interval(n, kOneSidedCoverageK2, kAlphaPerSide);
  const Coverage c = run_coverage(model, T_true, C, n, 4);
  std::printf("one feature: %d of %d above the bound, band [%lld, %lld]\n", c.rule, n,
              static_cast<long long>(band.low), static_cast<long long>(band.high));
  EXPECT_GE(c.rule, band.low);
  EXPECT_LE(c.rule, band.high);
  EXPECT_LT(c.mean_extra_margin_m, 1e-5);  // the rule costs nothing with one feature
}

// The closest feature switches: a 0.5 m bar's bottom face over the plane, its origin at the
// front end, pitched 2 mrad so that the back end is 1 mm nearer (truth). Pitch sigma 10 mrad
// gives the back end u = 5.1 mm, the front end u = 1 mm: estimates often find the front end
// nearest and its bound d - 2 (1 mm) misses the back end. The rule's bound sums the miss
// probabilities of both features; by the union bound its coverage is >= Phi(2) (one-sided
// test: the count must reach the band's lower end); the single-feature bound falls below it.
TEST(ClearanceUncertainty, FeatureSwitchRuleKeepsTheCoverageWhereTheSingleBoundLosesIt) {
  ClearanceModel model({store_body(test::box({0.25, 0, -0.05}, {0.25, 0.02, 0.05})), plane_body()});
  const Transform T_true = geometry::make_transform({0, -2e-3, 0}, {0.5, 0, -0.3});
  Vec6 sigma;
  sigma << 1e-3, 10e-3, 1e-3, 1e-3, 1e-3, 1e-3;
  const Mat6 C = Mat6(sigma.array().square().matrix().asDiagonal());
  const PartClearance at_truth = model.evaluate(T_true, C).at(0);
  EXPECT_GE(at_truth.features, 2);
  const int n = kCoverageDraws;
  const uncertainty::CountInterval band =
      uncertainty::binomial_interval(n, kOneSidedCoverageK2, kAlphaPerSide);
  const Coverage c = run_coverage(model, T_true, C, n, 5);
  std::printf(
      "feature switch: rule %d, single feature %d of %d above the bound, band [%lld, "
      "%lld], rule's extra margin %.3f mm\n",
      c.rule, c.single, n, static_cast<long long>(band.low), static_cast<long long>(band.high),
      1e3 * c.mean_extra_margin_m);
  EXPECT_GE(c.rule, band.low);
#ifdef STORETRACK_SANITIZE
  std::printf("single-feature loss of coverage not asserted at n = %d (Release: n = 3000)\n", n);
#else
  EXPECT_LT(c.single, band.low);
#endif
}

TEST(ClearanceUncertainty, PenetrationAndBadCovarianceAreReportedNotThrown) {
  ClearanceModel model({store_body(test::box({0, 0, 0}, {0.5, 0.2, 0.2})), plane_body()});
  Mat6 C = Mat6::Identity() * 1e-6;
  const PartClearance through =
      model.evaluate(geometry::make_transform({0, 0, 0}, {0, 0, -0.1}), C).at(0);
  EXPECT_TRUE(through.penetration);
  EXPECT_EQ(through.distance_m, 0.0);
  EXPECT_GT(through.u_distance_m, 0.0);
  EXPECT_LT(through.lower_bound_m, 0.0);
  C(2, 2) = std::nan("");
  const PartClearance nan =
      model.evaluate(geometry::make_transform({0, 0, 0}, {0, 0, -0.5}), C).at(0);
  EXPECT_NEAR(nan.distance_m, 0.3, 1e-12);
  EXPECT_TRUE(std::isnan(nan.lower_bound_m));
}

}  // namespace
}  // namespace storetrack::clearance
