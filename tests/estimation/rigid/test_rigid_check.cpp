// Rigid-body pair-distance chi-square test: the per-pair statistic is chi-square(1) for an
// intact body (so its exceedance rate matches the nominal level), the whole-body false alarm
// rate stays at or below the configured probability, and a displaced mark is found and excluded.
#include <random>

#include <gtest/gtest.h>

#include "storetrack/rigid/rigid_check.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::rigid {
namespace {

using geometry::Mat3;
using geometry::Vec3;

// A 16-mark body seen with independent noise plus shared calibration factors.
struct Scene {
  std::vector<Vec3> q;
  std::vector<Mat3> cov;
  std::vector<Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor>> loadings;
  std::vector<Mat3> chol;
};

Scene make_scene(std::mt19937_64& rng, int n, int factors) {
  std::uniform_real_distribution<double> u(-1, 1);
  Scene s;
  for (int i = 0; i < n; ++i) {
    s.q.emplace_back(u(rng), 0.15 * u(rng), 0.15 * u(rng));
    Mat3 A = Mat3::Random() * 4e-4;
    s.cov.push_back(A * A.transpose() + Mat3::Identity() * 1e-8);
    s.chol.push_back(s.cov.back().llt().matrixL());
    // Calibration loadings that vary smoothly across the body (distortion-like).
    Eigen::Matrix<double, 3, Eigen::Dynamic> L(3, factors);
    for (int j = 0; j < factors; ++j)
      L.col(j) = 1.5e-4 * Vec3(std::sin(j + 2 * s.q[i].x()), std::cos(j * s.q[i].y() + 1),
                               std::sin(0.5 * j + s.q[i].x() * s.q[i].z()));
    s.loadings.push_back(L);
  }
  return s;
}

std::vector<MarkEstimate> draw(const Scene& s, std::mt19937_64& rng, double survey_sigma,
                               int displaced = -1, double displacement = 0) {
  std::normal_distribution<double> n(0, 1);
  Eigen::VectorXd z(s.loadings[0].cols());
  for (int j = 0; j < z.size(); ++j)
    z(j) = n(rng);
  std::vector<MarkEstimate> marks(s.q.size());
  for (size_t i = 0; i < s.q.size(); ++i) {
    MarkEstimate& m = marks[i];
    m.id = 100 + static_cast<int>(i);
    m.p_body = s.q[i] + survey_sigma * Vec3(n(rng), n(rng), n(rng));  // surveyed (with error)
    m.survey_sigma_m = survey_sigma;
    m.p_w = s.q[i] + s.chol[i] * Vec3(n(rng), n(rng), n(rng)) + s.loadings[i] * z;
    if (static_cast<int>(i) == displaced) m.p_w += Vec3(0.6, 0.6, 0.53) * displacement;
    m.cov_independent = s.cov[i];
    m.loadings = &s.loadings[i];
  }
  return marks;
}

TEST(RigidCheck, PairStatisticIsChiSquareOne) {
  std::mt19937_64 rng(1);
  const Scene s = make_scene(rng, 16, 20);
  const double q95 = uncertainty::chi_square_quantile(uncertainty::Probability(0.95),
                                                      uncertainty::DegreesOfFreedom(1));
  int over = 0, total = 0;
  for (int trial = 0; trial < 400; ++trial) {
    const auto marks = draw(s, rng, 2e-4);
    for (size_t i = 0; i < marks.size(); ++i)
      for (size_t j = i + 1; j < marks.size(); ++j) {
        over += test_pair(marks[i], marks[j]).z2 > q95;
        ++total;
      }
  }
  // 48000 correlated pair statistics: the exceedance rate matches 5 % to about +-0.6 %.
  EXPECT_NEAR(static_cast<double>(over) / total, 0.05, 0.006);
}

TEST(RigidCheck, FalseAlarmRateAtMostConfigured) {
  std::mt19937_64 rng(2);
  const Scene s = make_scene(rng, 16, 20);
  RigidCheckConfig config;
  config.false_alarm_probability = 0.05;
  int alarms = 0;
  const int trials = 2000;
  for (int trial = 0; trial < trials; ++trial) {
    const auto marks = draw(s, rng, 2e-4);
    alarms += check_rigid_body(marks, config).failed;
  }
  const double rate = static_cast<double>(alarms) / trials;
  // Bonferroni over 120 pairs: the body false-alarm rate is <= alpha (2000 trials: +-0.5 %);
  // the pairs share marks, so it is lower, but it must not vanish (a test that never fires
  // at alpha has no power either).
  EXPECT_LE(rate, 0.05 + 0.012);
  EXPECT_GE(rate, 0.05 / 5);
}

TEST(RigidCheck, DisplacedMarkIsExcluded) {
  std::mt19937_64 rng(3);
  const Scene s = make_scene(rng, 16, 20);
  RigidCheckConfig config;
  int detected = 0, correct = 0;
  const int trials = 500;
  for (int trial = 0; trial < trials; ++trial) {
    const int bad = trial % 16;
    const auto marks = draw(s, rng, 2e-4, bad, 0.01);  // 10 mm: ~10 sigma of a distance
    const RigidCheckResult r = check_rigid_body(marks, config);
    detected += r.failed;
    correct += r.excluded_ids.size() == 1 && r.excluded_ids[0] == 100 + bad && r.consistent_after;
  }
  EXPECT_EQ(detected, trials);
  EXPECT_GE(correct, trials * 98 / 100);
}

TEST(RigidCheck, StopsAtMinimumMarks) {
  std::mt19937_64 rng(4);
  const Scene s = make_scene(rng, 3, 4);
  auto marks = draw(s, rng, 2e-4, 0, 0.05);
  RigidCheckConfig config;
  config.min_marks = 3;
  const RigidCheckResult r = check_rigid_body(marks, config);
  EXPECT_TRUE(r.failed);
  EXPECT_TRUE(r.excluded_ids.empty());
  EXPECT_FALSE(r.consistent_after);
}

// Without the pairs' statistics (the host without a rigid-body CSV, the replay) the decision is
// the full test's, exposure by exposure: intact bodies at a false alarm probability high enough
// that some fail, and bodies with a mark displaced by 0, 2 or 4 mm (~0, 2, 4 sigma of a
// distance), so that both the passing (no pairs formed) and the failing path (the full test)
// are taken.
TEST(RigidCheck, DecisionWithoutPairStatisticsIsTheFullTests) {
  std::mt19937_64 rng(5);
  const Scene s = make_scene(rng, 16, 20);
  RigidCheckConfig full;
  full.false_alarm_probability = 0.05;
  RigidCheckConfig decision = full;
  decision.pair_statistics = false;
  int passed = 0, failed = 0;
  for (int trial = 0; trial < 600; ++trial) {
    const double displacement = 2e-3 * (trial % 3);
    const auto marks = draw(s, rng, 2e-4, trial % 16, displacement);
    const RigidCheckResult a = check_rigid_body(marks, full);
    const RigidCheckResult b = check_rigid_body(marks, decision);
    ASSERT_EQ(a.failed, b.failed) << trial;
    ASSERT_EQ(a.excluded_ids, b.excluded_ids) << trial;
    ASSERT_EQ(a.excluded, b.excluded) << trial;
    ASSERT_EQ(a.consistent_after, b.consistent_after) << trial;
    ASSERT_EQ(a.pair_threshold_z2, b.pair_threshold_z2) << trial;
    ASSERT_EQ(a.pairs.size(), 120u);
    if (a.failed) {
      ++failed;
      ASSERT_EQ(b.pairs.size(), 120u) << trial;  // the full test's, field for field
      for (size_t k = 0; k < a.pairs.size(); ++k)
        ASSERT_EQ(a.pairs[k].z2, b.pairs[k].z2) << trial << " pair " << k;
      ASSERT_EQ(a.mean_z2, b.mean_z2) << trial;
    } else {
      ++passed;
      ASSERT_TRUE(b.pairs.empty()) << trial;
    }
  }
  // Both paths taken often enough to mean something (observed: 334 passed, 266 failed).
  EXPECT_GE(passed, 100) << passed << " passed, " << failed << " failed";
  EXPECT_GE(failed, 100) << passed << " passed, " << failed << " failed";
}

}  // namespace
}  // namespace storetrack::rigid
