// THE honesty test of storetrack (issue 3, "Uncertainty tagging"): over Monte Carlo runs of the
// simulator (calibration errors drawn from the stated covariances by calibrated_rig(), survey
// errors, centroid noise and trigger jitter in fast-mode observe()), the k = 2 intervals the
// host states must contain the truth 93-97 % of the time per axis, for marks and for the store
// pose, in the static scene and during store separation; the mean NEES of 3-D mark positions
// must be within 10 % of 3 (JCGM 101 validation of the JCGM 100 first-order propagation); the
// store attitude too, and the 6-DoF pose's mean NEES within 10 % of 6 (issue 10).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <random>

#include <gtest/gtest.h>

#include "honesty_bounds.hpp"
#include "sim_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack {
namespace {

using geometry::Vec3;
using Vec6 = Eigen::Matrix<double, 6, 1>;

// One independent calibration (simulator seed) per run: the calibration and survey errors
// dominate the pose budget and are common to all exposures of a run, so the number of runs is
// the effective sample size of the store-pose coverage. 1500 runs: coverage standard error
// 0.55 % (the 93-97 % band is 95.45 % -2.4/+1.5 points).
#ifdef STORETRACK_SANITIZE
constexpr int kRuns = 400;  // ASan/UBSan ~10x slower: standard error 1.0 %
#else
constexpr int kRuns = 1500;
#endif
// The first exposure of a run gives the tracker the marks' velocities (synchronisation term);
// the second, at a random instant of the scenario, is evaluated.
constexpr int kExposuresPerRun = 2;

struct Stats {
  uncertainty::ConsistencyAccumulator<3> marks;
  uncertainty::ConsistencyAccumulator<3> store_position;
  uncertainty::ConsistencyAccumulator<3> store_attitude;
  uncertainty::ConsistencyAccumulator<6> store_pose;  ///< (x, y, z, yaw, pitch, roll) jointly
  int exposures = 0, rigid_flags = 0;
  int refused_poses = 0;  ///< exposures the host gave no store pose (counted, not scored)
  std::array<double, 5> budget_m{};  ///< mean of u_x, centroid, intrinsic, extrinsic, sync
  int budget_n = 0;
};

void run_scene(const std::string& scenario_name, Stats& stats) {
  const sim::Scenario scenario = sim::load_scenario(test::scenario_path(scenario_name));
  std::mt19937_64 pick(12345);
  for (int run = 0; run < kRuns; ++run) {
    const sim::Simulator sim(scenario, 1000 + static_cast<std::uint64_t>(run));
    pipeline::ExposureProcessor proc(sim.calibrated_rig(), sim.pylon_survey(), sim.store_survey(),
                                     pipeline::ProcessorConfig{});
    std::uniform_int_distribution<int> start(0, sim.num_exposures() - kExposuresPerRun);
    const int k0 = start(pick);
    for (int k = k0; k < k0 + kExposuresPerRun; ++k) {
      const test::SimExposure in = test::make_exposure(sim, k);
      const pipeline::ExposureResult r = proc.process(in.exposure, in.ids);
      if (k == k0) continue;
      ++stats.exposures;
      const time::TaiNs t = r.reference_mid_tai_ns;
      for (const pipeline::MarkResult& m : r.marks) {
        if (m.excluded) continue;
        stats.marks.add(test::true_mark_in_host_world(sim, m.id, t) - m.p_w, m.cov_w);
      }
      if (r.pylon_check.failed || r.store_check.failed) ++stats.rigid_flags;
      if (!r.T_p_s.valid) {
        ++stats.refused_poses;
        continue;
      }
      const geometry::Transform T_true = sim.T_p_s_at(t);
      Vec6 e;
      e.head<3>() = T_true.translation() - r.T_p_s.T.translation();
      const Vec3 ypr_true = geometry::ypr_from_rotation(T_true.linear());
      for (int a = 0; a < 3; ++a)
        e(3 + a) = std::remainder(ypr_true(a) - r.xyz_ypr(3 + a), 2 * M_PI);
      stats.store_position.add(e.head<3>(), r.cov_xyz_ypr.topLeftCorner<3, 3>());
      const msg::FtiSample& f = r.sample;
      const double b[5] = {std::sqrt(f.u_x_m * f.u_x_m + f.u_y_m * f.u_y_m + f.u_z_m * f.u_z_m),
                           f.u_budget_centroid_m, f.u_budget_intrinsic_m, f.u_budget_extrinsic_m,
                           f.u_budget_sync_m};
      for (int i = 0; i < 5; ++i)
        stats.budget_m[static_cast<size_t>(i)] += b[i];
      ++stats.budget_n;
      stats.store_attitude.add(e.tail<3>(), r.cov_xyz_ypr.bottomRightCorner<3, 3>());
      stats.store_pose.add(e, r.cov_xyz_ypr);
    }
  }
  auto print = [](const char* what, const auto& acc) {
    std::printf("  %-16s n=%6lld coverage(k=2) %.4f %.4f %.4f  mean NEES %.3f\n", what,
                static_cast<long long>(acc.count()), acc.coverage(0), acc.coverage(1),
                acc.coverage(2), acc.mean_nees());
  };
  std::printf("scene %s: %d runs, %d exposures, rigid-body flags %d, store pose refused %d\n",
              scenario_name.c_str(), kRuns, stats.exposures, stats.rigid_flags,
              stats.refused_poses);
  const double n = std::max(stats.budget_n, 1);
  std::printf(
      "  T_p_s position u (RSS) %.3f mm: centroid %.3f, intrinsic %.3f, extrinsic+survey "
      "%.3f, sync %.4f mm (means)\n",
      stats.budget_m[0] / n * 1e3, stats.budget_m[1] / n * 1e3, stats.budget_m[2] / n * 1e3,
      stats.budget_m[3] / n * 1e3, stats.budget_m[4] / n * 1e3);
  print("marks (x,y,z)", stats.marks);
  print("T_p_s (x,y,z)", stats.store_position);
  print("T_p_s (y,p,r)", stats.store_attitude);
  std::printf("  T_p_s 6-DoF      n=%6lld mean NEES %.3f\n",
              static_cast<long long>(stats.store_pose.count()), stats.store_pose.mean_nees());
}

// The acceptance of issues 3 and 10: k = 2 coverage 93-97 % per axis of the store position and
// attitude, mean NEES of the 6-DoF pose within 10 % of 6; one sample per run, so the runs are
// independent and the derived band (honesty_bounds.hpp) widens it where kRuns is too small (the
// sanitizer tree's 400 runs). Marks: many per run, sharing the run's calibration errors, so not
// independent: the band as stated, and mean NEES within 10 % of 3. A refused pose is honest but
// must be rare: counted, and at most 1 % of the runs.
void expect_honest(const Stats& s) {
  ASSERT_GT(s.marks.count(), kRuns * 5);
  EXPECT_LE(s.refused_poses, kRuns / 100);
  ASSERT_EQ(s.store_position.count() + s.refused_poses, kRuns);
  const test::HonestyBounds required{0.93, 0.97, 6.0 * 0.9, 6.0 * 1.1};
  const test::HonestyBounds pose = test::widened(required, test::derived_bounds(kRuns, 6));
  std::printf("  acceptance (%d runs): store coverage [%.4f, %.4f], 6-DoF mean NEES [%.3f, %.3f]\n",
              kRuns, pose.coverage_low, pose.coverage_high, pose.nees_low, pose.nees_high);
  for (int a = 0; a < 3; ++a) {
    EXPECT_GE(s.marks.coverage(a), required.coverage_low) << "mark axis " << a;
    EXPECT_LE(s.marks.coverage(a), required.coverage_high) << "mark axis " << a;
    EXPECT_GE(s.store_position.coverage(a), pose.coverage_low) << "store position axis " << a;
    EXPECT_LE(s.store_position.coverage(a), pose.coverage_high) << "store position axis " << a;
    EXPECT_GE(s.store_attitude.coverage(a), pose.coverage_low) << "store attitude axis " << a;
    EXPECT_LE(s.store_attitude.coverage(a), pose.coverage_high) << "store attitude axis " << a;
  }
  EXPECT_NEAR(s.marks.mean_nees(), 3.0, 0.3);
  EXPECT_GE(s.store_pose.mean_nees(), pose.nees_low);
  EXPECT_LE(s.store_pose.mean_nees(), pose.nees_high);
}

// One scene per executable (STORETRACK_HONESTY_SCENE) keeps each under a minute.
TEST(UncertaintyHonesty, Scene) {
  Stats s;
  run_scene(STORETRACK_HONESTY_SCENE, s);
  expect_honest(s);
}

}  // namespace
}  // namespace storetrack
