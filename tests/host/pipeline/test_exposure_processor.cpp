// ExposureProcessor against simulator truth: marks and store pose vs truth, FtiSample fields
// and flags, the JCGM 101 Monte Carlo mode agreeing with the first-order covariance, bad input
// counted, displaced-mark exclusion end to end.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <initializer_list>

#include <gtest/gtest.h>

#include "sim_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"

namespace storetrack::pipeline {
namespace {

using geometry::Vec3;

struct Fixture {
  explicit Fixture(const std::string& scenario, std::uint64_t seed = 7)
      : sim(sim::load_scenario(test::scenario_path(scenario)), seed),
        proc(sim.calibrated_rig(), sim.pylon_survey(), sim.store_survey(), ProcessorConfig{}) {}
  sim::Simulator sim;
  ExposureProcessor proc;
};

// The survey loadings (issue 26: the smoother carries the survey error shared by all exposures)
// reproduce the pose's survey covariance: L_s L_s^T = cov_by_source[survey], 3 columns per
// surveyed mark of both bodies.
void expect_survey_loadings_reproduce_covariance(const PoseResult& pose, std::size_t marks) {
  const geometry::Mat6& survey = pose.cov_by_source[static_cast<std::size_t>(
      uncertainty::index(uncertainty::Source::kSurvey))];
  ASSERT_EQ(pose.survey_loadings.cols(), static_cast<Eigen::Index>(3 * marks));
  const geometry::Mat6 from_loadings = pose.survey_loadings * pose.survey_loadings.transpose();
  EXPECT_GT(survey.norm(), 0);
  EXPECT_LT((from_loadings - survey).norm(), 1e-12 * survey.norm());
}

TEST(ExposureProcessor, StoreSeparationPoseAgainstTruth) {
  Fixture f("store_separation");
  int valid = 0;
  for (int k = 0; k < f.sim.num_exposures(); k += 7) {
    const auto in = test::make_exposure(f.sim, k);
    const ExposureResult r = f.proc.process(in.exposure, in.ids);
    ASSERT_TRUE(r.T_p_s.valid) << k;
    ++valid;
    const std::size_t surveyed =
        f.sim.pylon_survey().marks.size() + f.sim.store_survey().marks.size();
    for (const PoseResult* pose : {&r.T_w_p, &r.T_w_s, &r.T_p_s})
      expect_survey_loadings_reproduce_covariance(*pose, surveyed);
    const geometry::Transform T_true = f.sim.T_p_s_at(r.reference_mid_tai_ns);
    const Vec3 e = T_true.translation() - r.T_p_s.T.translation();
    // Within 5 sigma per axis (the honesty test checks the 2-sigma coverage statistically).
    for (int a = 0; a < 3; ++a)
      EXPECT_LT(std::abs(e(a)), 5 * std::sqrt(r.cov_xyz_ypr(a, a))) << "k " << k << " axis " << a;
    EXPECT_LT(e.norm(), 0.01);  // and a few mm in absolute terms
    const msg::FtiSample& s = r.sample;
    EXPECT_TRUE(s.status & msg::fti_status::kValid);
    EXPECT_FALSE(s.status & msg::fti_status::kClockNotLocked);
    EXPECT_EQ(s.trigger_seq, in.exposure.trigger_seq);
    EXPECT_EQ(s.exposure_mid_tai_ns, r.reference_mid_tai_ns);
    EXPECT_FLOAT_EQ(s.x_m, static_cast<float>(r.T_p_s.T.translation().x()));
    EXPECT_FLOAT_EQ(s.coverage_factor, 2.0f);
    EXPECT_GT(s.u_x_m, 0);
    EXPECT_GT(s.u_budget_centroid_m, 0);
    EXPECT_GT(s.u_budget_intrinsic_m, 0);
    EXPECT_GT(s.u_budget_extrinsic_m, 0);
    // Budget components are independent: their variances add up to the total.
    const double total2 = s.u_x_m * s.u_x_m + s.u_y_m * s.u_y_m + s.u_z_m * s.u_z_m;
    const double parts2 = s.u_budget_centroid_m * s.u_budget_centroid_m +
                          s.u_budget_intrinsic_m * s.u_budget_intrinsic_m +
                          s.u_budget_extrinsic_m * s.u_budget_extrinsic_m +
                          s.u_budget_sync_m * s.u_budget_sync_m +
                          s.u_budget_process_m * s.u_budget_process_m;
    EXPECT_NEAR(parts2 / total2, 1.0, 1e-4);
    EXPECT_EQ(s.u_budget_process_m, 0.0f);  // measured, not extrapolated
    for (float c : s.correlation) {
      EXPECT_TRUE(std::isfinite(c));
      EXPECT_LE(std::abs(c), 1.0f + 1e-6f);
    }
    EXPECT_EQ(s.cameras_used, r.cameras_used);
    EXPECT_EQ(s.marks_used, r.T_w_s.marks_used);
    // Per-mark results: residuals per observation, covariance split.
    for (const MarkResult& m : r.marks) {
      EXPECT_GE(m.observations.size(), 2u);
      geometry::Mat3 sum = geometry::Mat3::Zero();
      for (const auto& c : m.cov_by_source)
        sum += c;
      EXPECT_LT((sum - m.cov_w).norm(), 1e-9 * m.cov_w.norm());
    }
  }
  EXPECT_GT(valid, 10);
  // After the first exposure the tracker provides velocities, so sync uncertainty is non-zero
  // once the store moves.
  EXPECT_EQ(f.proc.counters().pose_failed, 0u);
}

TEST(ExposureProcessor, WithMatcherIdentifiesAndTracksTheStore) {
  Fixture f("store_separation", 5);
  const sim::Scenario& sc = f.sim.scenario();
  geometry::Mat6 prior_cov = geometry::Mat6::Zero();
  prior_cov.diagonal() << 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4;  // ~0.6 deg, 1 cm
  ASSERT_TRUE(f.proc.matcher().set_prior_pose("pylon", sc.T_w_p, prior_cov));
  ASSERT_TRUE(f.proc.matcher().set_prior_pose("store", sc.T_w_p * sc.separation.T_p_s0, prior_cov));
  int valid = 0, wrong_ids = 0, identified = 0;
  for (int k = 0; k < f.sim.num_exposures(); ++k) {
    const auto in = test::make_exposure(f.sim, k);
    const ExposureResult r = f.proc.process(in.exposure);
    for (const MarkResult& m : r.marks)
      for (const auto& o : m.observations) {
        size_t e = 0;
        while (in.exposure.cameras[e].camera_id != o.camera_id)
          ++e;
        ++identified;
        wrong_ids += in.ids[e][static_cast<size_t>(o.mark_index)] != m.id;
      }
    if (!r.T_p_s.valid) continue;
    ++valid;
    const Vec3 e = f.sim.T_p_s_at(r.reference_mid_tai_ns).translation() - r.T_p_s.T.translation();
    for (int a = 0; a < 3; ++a)
      EXPECT_LT(std::abs(e(a)), 5 * std::sqrt(r.cov_xyz_ypr(a, a))) << "k " << k << " axis " << a;
  }
  std::printf("matcher: %d observations identified, %d wrong, %d of %d exposures with T_p_s\n",
              identified, wrong_ids, valid, f.sim.num_exposures());
  // Integration: ids from the matcher are never wrong (ambiguities are rejected, not guessed)
  // and most exposures give a pose; the matcher's own tests cover its acquisition rate.
  EXPECT_EQ(wrong_ids, 0);
  EXPECT_GT(identified, f.sim.num_exposures() * 30);
  EXPECT_GE(valid, f.sim.num_exposures() * 70 / 100);
}

// A result reused across exposures (its marks keep their storage; the mark count changes along
// the separation) holds what a new result per exposure holds, every number exactly.
TEST(ExposureProcessor, ReusedResultEqualsNewResultPerExposure) {
  Fixture by_value("store_separation", 5), reusing("store_separation", 5);
  const sim::Scenario& sc = by_value.sim.scenario();
  const geometry::Mat6 prior = geometry::Mat6::Identity() * 1e-4;
  for (Fixture* f : {&by_value, &reusing}) {
    ASSERT_TRUE(f->proc.matcher().set_prior_pose("pylon", sc.T_w_p, prior));
    ASSERT_TRUE(f->proc.matcher().set_prior_pose("store", sc.T_w_p * sc.separation.T_p_s0, prior));
  }
  ExposureResult reused;
  std::size_t min_marks = 1000, max_marks = 0;
  for (int k = 0; k < std::min(80, by_value.sim.num_exposures()); ++k) {
    const auto in = test::make_exposure(by_value.sim, k);
    const ExposureResult fresh = by_value.proc.process(in.exposure);
    reusing.proc.process(in.exposure, reused);
    ASSERT_EQ(fresh.marks.size(), reused.marks.size()) << "k " << k;
    min_marks = std::min(min_marks, fresh.marks.size());
    max_marks = std::max(max_marks, fresh.marks.size());
    for (std::size_t i = 0; i < fresh.marks.size(); ++i) {
      const MarkResult &a = fresh.marks[i], &b = reused.marks[i];
      EXPECT_EQ(a.id, b.id);
      EXPECT_EQ(a.excluded, b.excluded);
      EXPECT_EQ(a.p_w, b.p_w);
      EXPECT_EQ(a.cov_w, b.cov_w);
      EXPECT_EQ(a.loadings, b.loadings);
      ASSERT_EQ(a.observations.size(), b.observations.size());
      for (std::size_t o = 0; o < a.observations.size(); ++o)
        EXPECT_EQ(a.observations[o].residual_px, b.observations[o].residual_px);
    }
    EXPECT_EQ(fresh.T_p_s.valid, reused.T_p_s.valid);
    EXPECT_EQ(fresh.T_p_s.T.matrix(), reused.T_p_s.T.matrix());
    EXPECT_EQ(fresh.T_p_s.cov, reused.T_p_s.cov);
    EXPECT_EQ(fresh.cov_xyz_ypr, reused.cov_xyz_ypr);
    EXPECT_EQ(fresh.sample.status, reused.sample.status);
    EXPECT_EQ(fresh.sample.x_m, reused.sample.x_m);
    EXPECT_EQ(fresh.sample.u_x_m, reused.sample.u_x_m);
  }
  std::printf("reused result: %zu to %zu marks per exposure\n", min_marks, max_marks);
}

TEST(ExposureProcessor, MonteCarloAgreesWithFirstOrder) {
  Fixture f("store_separation", 11);
  const int k = f.sim.num_exposures() / 2;
  for (int j = k - 2; j < k; ++j) {  // tracking gives velocities for the sync term
    const auto in = test::make_exposure(f.sim, j);
    f.proc.process(in.exposure, in.ids);
  }
  const auto in = test::make_exposure(f.sim, k);
  const match::MatchResult marks = f.proc.identify(in.exposure, in.ids);
  const ExposureResult r = f.proc.process(in.exposure, marks);
  const MonteCarloResult mc = f.proc.monte_carlo(in.exposure, marks, 800, 99);
  ASSERT_GE(mc.draws, 790);
  // 800 draws: a sample standard deviation is within ~2.5 % (1 sigma) of the true one; the
  // first-order value must agree within 10 % on every pose axis and on mark positions.
  for (int a = 0; a < 6; ++a) {
    const double u_first = std::sqrt(r.cov_xyz_ypr(a, a));
    const double u_mc = std::sqrt(mc.cov_xyz_ypr(a, a));
    EXPECT_NEAR(u_mc / u_first, 1.0, 0.1) << "axis " << a;
  }
  int checked = 0;
  for (size_t i = 0; i < mc.mark_ids.size(); ++i) {
    const MarkResult* m = r.find_mark(mc.mark_ids[i]);
    ASSERT_NE(m, nullptr);
    for (int a = 0; a < 3; ++a)
      EXPECT_NEAR(std::sqrt(mc.mark_cov[i](a, a) / m->cov_w(a, a)), 1.0, 0.1)
          << "mark " << m->id << " axis " << a;
    ++checked;
  }
  EXPECT_GT(checked, 10);
}

TEST(ExposureProcessor, SingleCameraResectionMonteCarloAgreesWithFirstOrder) {
  // One camera left (every mark a single view): the pylon and store poses come from the
  // resection, flagged single_view; its first-order covariance (centroid, calibration loadings,
  // survey) against the JCGM 101 Monte Carlo of the same exposure, and the pose against truth.
  Fixture f("store_separation", 13);
  const int k = f.sim.num_exposures() / 2;
  for (int j = k - 2; j < k; ++j) {  // all cameras: the last solved poses start the resection
    const auto in = test::make_exposure(f.sim, j);
    ASSERT_TRUE(f.proc.process(in.exposure, in.ids).T_p_s.valid);
  }
  auto in = test::make_exposure(f.sim, k);
  const std::uint8_t kept_camera = in.exposure.cameras.front().camera_id;
  for (size_t e = in.exposure.cameras.size(); e-- > 0;)
    if (in.exposure.cameras[e].camera_id != kept_camera) {
      in.exposure.cameras.erase(in.exposure.cameras.begin() + static_cast<long>(e));
      in.ids.erase(in.ids.begin() + static_cast<long>(e));
    }
  ASSERT_EQ(in.exposure.cameras.size(), 1u);
  const match::MatchResult marks = f.proc.identify(in.exposure, in.ids);
  const ExposureResult r = f.proc.process(in.exposure, marks);
  ASSERT_TRUE(r.T_p_s.valid);
  EXPECT_TRUE(r.single_view_pose);
  expect_survey_loadings_reproduce_covariance(
      r.T_p_s, f.sim.pylon_survey().marks.size() + f.sim.store_survey().marks.size());
  EXPECT_TRUE(r.sample.status & msg::fti_status::kSingleView);
  const geometry::Transform T_true = f.sim.T_p_s_at(r.reference_mid_tai_ns);
  const Vec3 e = T_true.translation() - r.T_p_s.T.translation();
  for (int a = 0; a < 3; ++a)
    EXPECT_LT(std::abs(e(a)), 5 * std::sqrt(r.cov_xyz_ypr(a, a))) << "axis " << a;
  const MonteCarloResult mc = f.proc.monte_carlo(in.exposure, marks, 800, 98);
  ASSERT_GE(mc.draws, 790);
  // 800 draws: a sample standard deviation within ~2.5 % (1 sigma) of the true one; the
  // first-order value must agree within 10 % on every pose axis (as for the triangulated path).
  for (int a = 0; a < 6; ++a) {
    const double u_first = std::sqrt(r.cov_xyz_ypr(a, a));
    const double u_mc = std::sqrt(mc.cov_xyz_ypr(a, a));
    std::printf("axis %d: first order %.3g, Monte Carlo %.3g\n", a, u_first, u_mc);
    EXPECT_NEAR(u_mc / u_first, 1.0, 0.1) << "axis " << a;
  }
}

TEST(ExposureProcessor, DisplacedMarkIsExcludedAndFlagged) {
  Fixture f("static");
  auto in = test::make_exposure(f.sim, 10);
  // Move one store mark's image in every camera by 6 px: the point moves by several mm.
  int target = -1;
  for (size_t e = 0; e < in.exposure.cameras.size(); ++e)
    for (size_t j = 0; j < in.ids[e].size(); ++j)
      if (in.ids[e][j] >= 100 && in.ids[e][j] < 200 && target < 0) target = in.ids[e][j];
  ASSERT_GE(target, 0);
  int moved = 0;
  for (size_t e = 0; e < in.exposure.cameras.size(); ++e)
    for (size_t j = 0; j < in.ids[e].size(); ++j)
      if (in.ids[e][j] == target) {
        in.exposure.cameras[e].marks[j].y_px += 6.0f;
        ++moved;
      }
  ASSERT_GE(moved, 2);
  const ExposureResult r = f.proc.process(in.exposure, in.ids);
  ASSERT_EQ(r.store_check.excluded_ids.size(), 1u);
  EXPECT_EQ(r.store_check.excluded_ids[0], target);
  EXPECT_TRUE(r.sample.status & msg::fti_status::kRigidBodyFailed);
  EXPECT_TRUE(r.T_p_s.valid);
  EXPECT_TRUE(r.find_mark(target)->excluded);
  EXPECT_EQ(f.proc.counters().marks_excluded, 1u);
}

// Issue 11: a blob cut by the image edge (kBorder) has its centroid pulled inwards by up to a
// radius, a bias its sigma_px does not state. The matcher never identifies such blobs; ids
// given from outside (simulator truth, an external matcher) must not bring them back: with two
// cameras left they passed the epipolar and rigid-body checks and made the store attitude's
// stated uncertainty too small (docs/uncertainty.md). Rejected and counted, not used.
TEST(ExposureProcessor, BorderCutBlobIsNotUsedEvenWithGivenIds) {
  Fixture f("static");
  auto in = test::make_exposure(f.sim, 10);
  size_t e_cut = 0, j_cut = 0;
  int target = -1;
  for (size_t e = 0; e < in.exposure.cameras.size() && target < 0; ++e)
    for (size_t j = 0; j < in.ids[e].size() && target < 0; ++j)
      if (in.ids[e][j] >= 100 && in.ids[e][j] < 200) {
        target = in.ids[e][j];
        e_cut = e;
        j_cut = j;
      }
  ASSERT_GE(target, 0);
  // The matcher counts every flagged observation of the exposure, identified or not: the
  // unmodified exposure's count is the baseline.
  Fixture unmodified("static");
  unmodified.proc.process(in.exposure, in.ids);
  const std::uint64_t baseline = unmodified.proc.matcher().counters().rejected_by_flags;
  msg::MarkObservation& cut = in.exposure.cameras[e_cut].marks[j_cut];
  ASSERT_FALSE(cut.flags & msg::mark_flags::kBorder);
  cut.flags |= msg::mark_flags::kBorder;
  cut.x_px += 3.0f;  // the pull of a cut blob (docs/performance.md: 3 px at u = 1917.6)
  const ExposureResult r = f.proc.process(in.exposure, in.ids);
  EXPECT_EQ(f.proc.matcher().counters().rejected_by_flags, baseline + 1);
  for (const MarkResult& m : r.marks)
    for (const MarkResult::ObservationResidual& o : m.observations)
      EXPECT_FALSE(o.camera_id == in.exposure.cameras[e_cut].camera_id &&
                   o.mark_index == static_cast<int>(j_cut))
          << "mark " << m.id << " uses the border-cut blob";
}

// One row of store marks (the same clock position at three stations) is collinear: the roll about
// the row is left to the survey noise. The processor must refuse that pose, not publish it with
// a linearised covariance that no longer holds; one more mark off the row makes it valid again.
TEST(ExposureProcessor, CollinearStoreMarksAreRefusedNotTrusted) {
  const auto keep_only = [](test::SimExposure in, std::initializer_list<int> store_ids) {
    for (auto& cam : in.ids)
      for (int& id : cam)
        if (id >= 100 && std::find(store_ids.begin(), store_ids.end(), id) == store_ids.end())
          id = -1;
    return in;
  };
  Fixture f("static");
  const auto row = keep_only(test::make_exposure(f.sim, 10), {104, 108, 112});
  const ExposureResult r = f.proc.process(row.exposure, row.ids);
  EXPECT_FALSE(r.T_p_s.valid);
  EXPECT_FALSE(r.sample.status & msg::fti_status::kValid);
  EXPECT_TRUE(r.sample.status & msg::fti_status::kDegradedGeometry);
  EXPECT_EQ(f.proc.counters().degenerate_geometry, 1u);
  EXPECT_TRUE(r.T_w_p.valid);  // the pylon's marks are fine

  const auto off_row = keep_only(test::make_exposure(f.sim, 11), {104, 108, 112, 107});
  const ExposureResult r2 = f.proc.process(off_row.exposure, off_row.ids);
  EXPECT_TRUE(r2.T_p_s.valid);
  EXPECT_EQ(f.proc.counters().degenerate_geometry, 1u);
}

TEST(ExposureProcessor, BadInputIsCountedNotUsed) {
  Fixture f("static");
  auto in = test::make_exposure(f.sim, 3);
  auto first_identified = [&](size_t e) {
    size_t j = 0;
    while (j < in.ids[e].size() && in.ids[e][j] < 0)
      ++j;
    return j;
  };
  const size_t j0 = first_identified(0), j2 = first_identified(2);
  ASSERT_LT(j0, in.ids[0].size());
  ASSERT_LT(j2, in.ids[2].size());
  in.exposure.cameras[0].marks[j0].sigma_px = std::nanf("");  // the matcher's fallback sigma
  in.exposure.cameras[1].camera_id = 200;                     // not in the calibration
  in.ids[2][j2] = 5000;                                       // id out of range
  const ExposureResult r = f.proc.process(in.exposure, in.ids);
  EXPECT_EQ(f.proc.counters().unknown_camera, 1u);
  EXPECT_EQ(f.proc.matcher().counters().unknown_camera, 1u);
  EXPECT_EQ(f.proc.matcher().counters().fallback_sigma, 1u);
  EXPECT_EQ(f.proc.counters().id_out_of_range, 1u);
  EXPECT_TRUE(r.sample.status & msg::fti_status::kCameraMissing);
  EXPECT_TRUE(r.sample.status & msg::fti_status::kDegradedGeometry);
  // Before release each store mark is seen by one camera pair (0+1 or 2+3): without camera 1
  // only the row 107/111/115 is triangulated, collinear, so the store pose is refused.
  EXPECT_TRUE(r.T_w_p.valid);
  EXPECT_FALSE(r.T_p_s.valid);
  EXPECT_EQ(f.proc.counters().degenerate_geometry, 1u);
  pipeline::MarkIds short_ids = in.ids;
  short_ids.pop_back();
  EXPECT_THROW(f.proc.process(in.exposure, short_ids), std::invalid_argument);
}

// A unit's stated time uncertainty (MarkObservations.exposure_time_sigma_ns) enters the sync
// budget: its clock column's loadings are linear in the figure, so a mark's sync variance is
// A + B s^2 exactly (three figures give A and B, the fourth must follow), with B > 0 for the marks
// unit 1's cameras see while they move. A unit in holdover (its figure grown to 200 us: 200 s at
// 1 ppm) then dominates the sync budget of the samples it contributes to. A figure the unit did
// not state (0xFFFFFFFF) is counted and adds nothing (as a figure of 0).
TEST(ExposureProcessor, StatedTimeUncertaintyOfAUnitInHoldoverGrowsTheSyncBudget) {
  const int k = 150;  // the store is well under way: the sync term moves with its speed
  std::uint64_t unknown = 0;
  const auto run = [&](std::uint32_t sigma_ns) {
    Fixture f("store_separation", 11);
    for (int j = k - 2; j < k; ++j) {  // tracking gives velocities for the sync term
      const auto in = test::make_exposure(f.sim, j);
      f.proc.process(in.exposure, in.ids);
    }
    auto in = test::make_exposure(f.sim, k);
    for (msg::MarkObservations& o : in.exposure.cameras)
      if (o.unit_id == 1) o.exposure_time_sigma_ns = sigma_ns;
    const ExposureResult r = f.proc.process(in.exposure, in.ids);
    EXPECT_TRUE(r.T_p_s.valid);
    unknown = f.proc.counters().time_sigma_unknown;
    return r;
  };
  const double s1 = 200e-9, s2 = 20e-6, s3 = 200e-6;
  const ExposureResult r1 = run(200), r2 = run(20'000), r3 = run(200'000);
  EXPECT_EQ(unknown, 0u);
  const ExposureResult r0 = run(msg::mark_observations_invalid::kExposureTimeSigmaNs);
  EXPECT_EQ(unknown, 2u);  // unit 1's two cameras
  const auto sync = [](const ExposureResult& r, int id) {
    const MarkResult* m = r.find_mark(id);
    return m == nullptr ? -1.0
                        : m->cov_by_source[static_cast<std::size_t>(
                                               uncertainty::index(uncertainty::Source::kSync))]
                              .trace();
  };
  int moving = 0;
  for (const MarkResult& m : r1.marks) {
    const double v1 = sync(r1, m.id), v2 = sync(r2, m.id), v3 = sync(r3, m.id);
    const double v0 = sync(r0, m.id);
    ASSERT_GE(std::min({v2, v3, v0}), 0.0) << "mark " << m.id << " not solved in every run";
    const double b = (v2 - v1) / (s2 * s2 - s1 * s1);
    EXPECT_NEAR(v3, v1 + b * (s3 * s3 - s1 * s1), 1e-9 * v3 + 1e-30) << "mark " << m.id;
    EXPECT_NEAR(v0, v1 - b * s1 * s1, 1e-9 * v1 + 1e-30) << "mark " << m.id;
    EXPECT_GE(b, -1e-12 * v1 / (s1 * s1));
    if (b * s3 * s3 > 100 * v1) ++moving;
  }
  EXPECT_GT(moving, 5);  // the store's marks seen by unit 1
  const double u1 = r1.sample.u_budget_sync_m, u2 = r2.sample.u_budget_sync_m,
               u3 = r3.sample.u_budget_sync_m;
  EXPECT_LT(u1, u2);
  EXPECT_LT(u2, u3);
  EXPECT_GT(u3, 10 * u1);
  std::printf(
      "u_budget_sync with unit 1 stating 0.2 / 20 / 200 us: %.4f / %.4f / %.4f mm; "
      "%d marks dominated by it at 200 us\n",
      1e3 * u1, 1e3 * u2, 1e3 * u3, moving);
}

TEST(ExposureProcessor, ClockNotLockedIsFlagged) {
  Fixture f("static");
  auto in = test::make_exposure(f.sim, 4);
  in.exposure.cameras[2].clock_state = static_cast<std::uint8_t>(time::ClockState::kHoldover);
  const ExposureResult r = f.proc.process(in.exposure, in.ids);
  EXPECT_TRUE(r.sample.status & msg::fti_status::kClockNotLocked);
}

}  // namespace
}  // namespace storetrack::pipeline
