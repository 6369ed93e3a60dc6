// PoseTracker (issue 3, FtiSample status bit "extrapolated"; issue 10: two-sided): store
// separation in the simulator with the store marks hidden for several exposures. Over
// independent simulator seeds (calibration, survey and centroid errors drawn from their stated
// distributions, and the store's relative accelerations drawn from the tracker's stated
// envelope), the k = 2 intervals of the extrapolated samples must contain the truth as often as
// they claim, neither more nor less, the flag must be set exactly on the samples predicted
// within the configured gap, and later samples must be invalid.
#include <algorithm>
#include <array>
#include <cfloat>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "honesty_bounds.hpp"
#include "sim_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/pipeline/pose_tracker.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::pipeline {
namespace {

using geometry::Vec3;
using Vec6 = Eigen::Matrix<double, 6, 1>;

#ifdef STORETRACK_SANITIZE
constexpr int kSeeds = 20;  // ASan/UBSan ~10x slower: a smoke run (the band follows n = 20)
#else
constexpr int kSeeds = 200;  // seeds are the effective sample (own calibration each): s.e. 1.5 %
#endif
constexpr int kSolvedBefore = 3;  // exposures with all marks before the store marks vanish
constexpr int kHidden = 10;       // 25 ms at 400 fps: longer than the 20 ms gap

// STORETRACK_TRACKER_SEEDS=N: the full form (docs/uncertainty.md); the band follows N.
int seeds_from_env() {
  const char* v = std::getenv("STORETRACK_TRACKER_SEEDS");
  return v ? std::max(20, std::atoi(v)) : kSeeds;
}

bool is_store_mark(int id) {
  return id >= 100 && id < 200;
}

void hide_store_marks(test::SimExposure& in) {
  for (auto& ids : in.ids)
    for (int& id : ids)
      if (is_store_mark(id)) id = -1;  // unidentified: not used
}

// truth - estimate of (x, y, z, yaw, pitch, roll).
Vec6 error_to_truth(const sim::Simulator& sim, const ExposureResult& r) {
  const geometry::Transform T_true = sim.T_p_s_at(r.reference_mid_tai_ns);
  Vec6 e;
  e.head<3>() = T_true.translation() - r.xyz_ypr.head<3>();
  const Vec3 ypr_true = geometry::ypr_from_rotation(T_true.linear());
  for (int a = 0; a < 3; ++a)
    e(3 + a) = std::remainder(ypr_true(a) - r.xyz_ypr(3 + a), 2 * M_PI);
  return e;
}

// The k = 2 scores of one tracker configuration over the gaps.
struct GapScores {
  uncertainty::ConsistencyAccumulator<3> position, attitude, position_short, attitude_short,
      position_long, attitude_long;
  int extrapolated = 0, invalid_after_gap = 0;
  double sum_u_z_short = 0, sum_u_z_long = 0;
};

struct TrackerVariant {
  const char* name;
  PoseTrackerConfig config;
  GapScores scores;
};

void print_scores(const char* what, const uncertainty::ConsistencyAccumulator<3>& acc) {
  std::printf("    %-26s n=%5lld coverage(k=2) %.4f %.4f %.4f  mean NEES %.3f\n", what,
              static_cast<long long>(acc.count()), acc.coverage(0), acc.coverage(1),
              acc.coverage(2), acc.mean_nees());
}

// Outside the acceptance on any axis, or its mean NEES outside the chi-square band.
bool rejected(const uncertainty::ConsistencyAccumulator<3>& acc, const test::HonestyBounds& b) {
  bool out = acc.mean_nees() < b.nees_low || acc.mean_nees() > b.nees_high;
  for (int a = 0; a < 3; ++a)
    out = out || acc.coverage(a) < b.coverage_low || acc.coverage(a) > b.coverage_high;
  return out;
}

// The store's stated dynamics envelope (docs/uncertainty.md, "Process model"): per axis, its
// aerodynamic specific force [m/s^2] about the fall with the aircraft's load factor, and its
// angular acceleration [rad/s^2] about zero. The product defaults state it (checked below).
constexpr double kEnvelopeAccel = 5.0;
constexpr double kEnvelopeAngularAccel = 2.0;

// The store's relative accelerations of one test point, drawn from the envelope (a random
// constant per axis): the scenario's gravity along z_p plus the aerodynamic spread, angular
// accelerations about zero. The scenario's own values (-3, 0.4, 0) m/s^2 and (0.1, 0.8, 0)
// rad/s^2 are one such draw, each within 1 sigma.
// STORETRACK_TRACKER_SCENARIO_DYNAMICS=1 keeps them instead (docs/uncertainty.md).
void draw_dynamics(sim::Scenario& sc, std::mt19937_64& rng) {
  if (std::getenv("STORETRACK_TRACKER_SCENARIO_DYNAMICS")) return;
  std::normal_distribution<double> n01;
  sc.separation.accel_p_m_s2 = Vec3(0, 0, sc.separation.accel_p_m_s2.z());
  for (int a = 0; a < 3; ++a) {
    sc.separation.accel_p_m_s2(a) += kEnvelopeAccel * n01(rng);
    sc.separation.accel_ypr_rad_s2(a) = kEnvelopeAngularAccel * n01(rng);
  }
}

// The processor's sample of an unsolved exposure carries what its own tracker predicted (one
// writer): valid | extrapolated with the prediction's pose and uncertainty, else invalid.
void check_sample_of_hidden(const ExposureResult& r) {
  const std::uint16_t status = r.sample.status;
  if (!r.extrapolated) {
    EXPECT_FALSE(status & msg::fti_status::kValid);
    EXPECT_FALSE(status & msg::fti_status::kExtrapolated);
    EXPECT_TRUE(std::isnan(r.sample.x_m));
    return;
  }
  EXPECT_EQ(status & (msg::fti_status::kValid | msg::fti_status::kExtrapolated),
            msg::fti_status::kValid | msg::fti_status::kExtrapolated);
  EXPECT_FLOAT_EQ(static_cast<float>(r.xyz_ypr(2)), r.sample.z_m);
  EXPECT_FLOAT_EQ(r.sample.u_z_m, static_cast<float>(std::sqrt(r.cov_xyz_ypr(2, 2))));
}

// Scores one extrapolated or past-the-gap exposure of one tracker variant (on its own copy of
// the processor's result and its own motion state: the variant's prediction replaces the
// processor's).
void score_hidden(const sim::Simulator& sim, ExposureResult r, PoseTracker& tracker,
                  match::BodyMotion& motion, time::TaiNs last_solved_ns, double frame_s,
                  GapScores& g) {
  const bool did = tracker.update(r, motion);
  ASSERT_EQ(did, r.extrapolated);
  const double tau = static_cast<double>(r.reference_mid_tai_ns - last_solved_ns) * 1e-9;
  if (tau > tracker.config().max_gap_s) {
    EXPECT_FALSE(did);  // beyond the gap: no prediction
    ++g.invalid_after_gap;
    return;
  }
  ASSERT_TRUE(did) << "tau " << tau;
  EXPECT_NEAR(r.extrapolation_horizon_s, tau, 1e-12);
  EXPECT_TRUE(std::isfinite(r.xyz_ypr(2)));
  ++g.extrapolated;
  const Vec6 e = error_to_truth(sim, r);
  const auto C_pos = r.cov_xyz_ypr.topLeftCorner<3, 3>();
  const auto C_att = r.cov_xyz_ypr.bottomRightCorner<3, 3>();
  g.position.add(e.head<3>(), C_pos);
  g.attitude.add(e.tail<3>(), C_att);
  if (tau < 1.5 * frame_s) {
    g.position_short.add(e.head<3>(), C_pos);
    g.attitude_short.add(e.tail<3>(), C_att);
    g.sum_u_z_short += std::sqrt(r.cov_xyz_ypr(2, 2));
  } else if (tau > 6.5 * frame_s) {
    g.position_long.add(e.head<3>(), C_pos);
    g.attitude_long.add(e.tail<3>(), C_att);
    g.sum_u_z_long += std::sqrt(r.cov_xyz_ypr(2, 2));
  }
}

// Where the gaps fall: their first solved exposure k0 uniform in [first_s, last_s] of the
// scenario's time (last_s < 0: as late as the run allows). The trackers are fed, unscored, the
// exposures from k0 - lead_in on, or with `pair_only` the first two of them only (a velocity
// pair: enough to have seen the store move, at a fraction of the cost).
struct GapPlacement {
  double first_s = 0, last_s = -1;
  int lead_in = 0;
  bool pair_only = false;
};

// One pass over the seeds; every variant's tracker sees the same processed exposures (the
// processor's work is shared, the trackers are cheap).
// Counts the gaps scored. A seed whose visible exposures before the gap are not all
// solved (with a large drawn acceleration the store leaves the cameras' view late in the run)
// is left out, counted and listed, not scored.
void run_gaps(std::vector<TrackerVariant>& variants, int seeds, const GapPlacement& placement,
              uncertainty::ConsistencyAccumulator<3>& solved_attitude, int& gaps) {
  gaps = 0;
  const sim::Scenario base = sim::load_scenario(test::scenario_path("store_separation"));
  const double frame_s = 1.0 / base.frame_rate_hz;
  const int first_k = static_cast<int>(std::ceil(placement.first_s / frame_s));
  const int last_k_run = base.num_exposures - kSolvedBefore - kHidden - 2;
  const int last_k =
      placement.last_s < 0
          ? last_k_run
          : std::min(last_k_run, static_cast<int>(std::floor(placement.last_s / frame_s)));
  std::mt19937_64 pick(4242), dynamics(777);
  for (int seed = 0; seed < seeds; ++seed) {
    sim::Scenario scenario = base;
    draw_dynamics(scenario, dynamics);
    const sim::Simulator sim(scenario, 5000 + static_cast<std::uint64_t>(seed));
    ExposureProcessor proc(sim.calibrated_rig(), sim.pylon_survey(), sim.store_survey(),
                           ProcessorConfig{});
    std::vector<PoseTracker> trackers;
    for (const TrackerVariant& v : variants)
      trackers.emplace_back(proc.factors(), v.config);
    std::vector<match::BodyMotion> motions(variants.size());  // each variant's store
    std::uniform_int_distribution<int> start(first_k, last_k);
    const int k0 = start(pick);
    time::TaiNs last_solved_ns = 0;
    bool left_out = false;
    const int lead_in_first = std::max(0, k0 - placement.lead_in);
    for (int k = lead_in_first; k < k0; ++k) {
      if (placement.pair_only && k > lead_in_first + 1) break;
      const test::SimExposure in = test::make_exposure(sim, k);
      const ExposureResult r = proc.process(in.exposure, in.ids);
      for (size_t i = 0; i < trackers.size(); ++i) {
        ExposureResult copy = r;
        trackers[i].update(copy, motions[i]);
      }
    }
    for (int k = k0; k < k0 + kSolvedBefore + kHidden + 1 && !left_out; ++k) {
      test::SimExposure in = test::make_exposure(sim, k);
      const bool hidden = k >= k0 + kSolvedBefore && k < k0 + kSolvedBefore + kHidden;
      if (hidden) hide_store_marks(in);
      const ExposureResult r = proc.process(in.exposure, in.ids);
      if (!hidden) {
        // All marks visible: solved, never flagged.
        if (!r.T_p_s.valid && k < k0 + kSolvedBefore) {
          std::printf("  left out: seed %d, exposure %d before the gap not solved (status 0x%x)\n",
                      seed, k, static_cast<unsigned>(r.sample.status));
          left_out = true;
          continue;
        }
        if (!r.T_p_s.valid) continue;  // after the gap: the gap is scored already
        for (size_t i = 0; i < trackers.size(); ++i) {
          ExposureResult copy = r;
          EXPECT_FALSE(trackers[i].update(copy, motions[i]));
          EXPECT_FALSE(copy.sample.status & msg::fti_status::kExtrapolated);
          EXPECT_TRUE(copy.sample.status & msg::fti_status::kValid);
        }
        last_solved_ns = r.reference_mid_tai_ns;
        solved_attitude.add(error_to_truth(sim, r).tail<3>(),
                            r.cov_xyz_ypr.bottomRightCorner<3, 3>());
        continue;
      }
      ASSERT_FALSE(r.T_p_s.valid);  // no store marks: the pose cannot be solved
      check_sample_of_hidden(r);
      for (size_t i = 0; i < variants.size(); ++i)
        score_hidden(sim, r, trackers[i], motions[i], last_solved_ns, frame_s, variants[i].scores);
    }
    if (!left_out) ++gaps;
  }
}

// The product defaults against accelerations drawn from their stated envelope: whole-gap k = 2
// coverage per axis (position and attitude) and mean NEES two-sided. Deliberately mis-scaled
// process noise (x 0.3, x 3) and the old model (no mean, 20 m/s^2, 5 rad/s^2) must be rejected
// by the same acceptance, or the test could not tell an honest tracker from a wrong one.
TEST(PoseTracker, ExtrapolatesHonestlyWithinTheGapAndStopsAfterIt) {
  const int seeds = seeds_from_env();
  const PoseTrackerConfig product;
  ASSERT_EQ(product.max_gap_s, 0.02);
  EXPECT_EQ(product.accel_sigma_m_s2, kEnvelopeAccel);
  EXPECT_EQ(product.angular_accel_sigma_rad_s2, kEnvelopeAngularAccel);
  PoseTrackerConfig low = product, high = product, old_model = product;
  low.accel_sigma_m_s2 *= 0.3;
  low.angular_accel_sigma_rad_s2 *= 0.3;
  high.accel_sigma_m_s2 *= 3;
  high.angular_accel_sigma_rad_s2 *= 3;
  old_model.mean_accel_p_m_s2.setZero();
  old_model.accel_sigma_m_s2 = 20;
  old_model.angular_accel_sigma_rad_s2 = 5;
  std::vector<TrackerVariant> variants = {{"product defaults", product, GapScores()},
                                          {"process noise x 0.3", low, GapScores()},
                                          {"process noise x 3", high, GapScores()},
                                          {"old model (0 mean, 20, 5)", old_model, GapScores()}};
  uncertainty::ConsistencyAccumulator<3> solved_attitude;
  int gaps = 0;
  // In free flight: after the release (20 ms) and the release zone (first motion + 80 ms); the
  // trackers see the store move in a solved pair 40 exposures (100 ms) before the gap's k0.
  run_gaps(variants, seeds, GapPlacement{0.125, -1, 40, true}, solved_attitude, gaps);
  // Left-out seeds are counted (none of the CI's 200); more than 1 % would be a regression.
  EXPECT_GE(gaps, seeds - seeds / 100) << seeds - gaps << " of " << seeds << " seeds left out";

  // Acceptance. n = 8 samples per gap x gaps, but the samples of one gap share the seed's
  // calibration, survey, accelerations and the two tracked poses: the effective sample size is
  // 8 gaps / (1 + 7 rho), between gaps (rho = 1) and 8 gaps (rho = 0). The band of n_eff =
  // gaps is the widest the correlation allows (binomial 95.45 %, alpha 0.001 per side; mean NEES
  // of d = 3: chi-square(3 gaps) / gaps), so an honest tracker fails it with <= 0.2 % per check.
  const test::HonestyBounds band = test::derived_bounds(gaps, 3);
  std::printf(
      "%d seeds, %d gaps scored; acceptance (n_eff = %d): coverage [%.4f, %.4f], mean "
      "NEES (d=3) [%.3f, %.3f]\n",
      seeds, gaps, gaps, band.coverage_low, band.coverage_high, band.nees_low, band.nees_high);
  for (const TrackerVariant& v : variants) {
    const GapScores& g = v.scores;
    std::printf("  %s: %d extrapolated, %d invalid after the gap\n", v.name, g.extrapolated,
                g.invalid_after_gap);
    print_scores("position (x,y,z)", g.position);
    print_scores("attitude (y,p,r)", g.attitude);
    print_scores("position, 1 frame ahead", g.position_short);
    print_scores("position, >= 7 frames ahead", g.position_long);
    print_scores("attitude, 1 frame ahead", g.attitude_short);
    print_scores("attitude, >= 7 frames ahead", g.attitude_long);
    std::printf("    mean u_z: 1 frame ahead %.3f mm, >= 7 frames ahead %.3f mm\n",
                g.sum_u_z_short / std::max<double>(g.position_short.count(), 1) * 1e3,
                g.sum_u_z_long / std::max<double>(g.position_long.count(), 1) * 1e3);
    // 20 ms gap at 2.5 ms per exposure: 8 extrapolated and 2 invalid samples per seed (exposure
    // times jitter by ~1 us, which may move the 8th just past the gap).
    EXPECT_GE(g.extrapolated, gaps * 7) << v.name;
    EXPECT_GE(g.invalid_after_gap, gaps * 2) << v.name;
  }
  print_scores("attitude, solved exposures", solved_attitude);
  // One test point is one draw of the envelope: its fixed accelerations give every seed the same
  // bias, so the coverage over seeds scores that one bias, not the stated distribution (which
  // is over the test points of the envelope). Printed, not scored.
  if (std::getenv("STORETRACK_TRACKER_SCENARIO_DYNAMICS"))
    GTEST_SKIP() << "the scenario's own accelerations: one draw of the envelope, not scored";

  const GapScores& g = variants[0].scores;
  for (int a = 0; a < 3; ++a) {
    for (const auto& [what, acc] : {std::pair{"position, whole gap", &g.position},
                                    std::pair{"attitude, whole gap", &g.attitude},
                                    std::pair{"position 1 frame ahead", &g.position_short},
                                    std::pair{"attitude 1 frame ahead", &g.attitude_short}}) {
      EXPECT_GE(acc->coverage(a), band.coverage_low) << what << ", axis " << a;
      EXPECT_LE(acc->coverage(a), band.coverage_high) << what << ", axis " << a;
    }
  }
  for (const auto& [what, acc] : {std::pair{"position, whole gap", &g.position},
                                  std::pair{"attitude, whole gap", &g.attitude}}) {
    EXPECT_GE(acc->mean_nees(), band.nees_low) << what;
    EXPECT_LE(acc->mean_nees(), band.nees_high) << what;
  }
  for (size_t i = 1; i < variants.size(); ++i) {
    const GapScores& w = variants[i].scores;
    EXPECT_TRUE(rejected(w.position, band) || rejected(w.attitude, band))
        << variants[i].name << " passes the acceptance: the test cannot see it";
  }
}

// Through the release: gaps that begin on the captive store, across the release (20 ms) and in
// the ejector's 50 ms stroke (80 m/s^2, pitch rate ramping at 12 rad/s^2), where the free-flight
// model (mean 1 g, 5 m/s^2) fell 8-14 sigma short in live runs that lost cameras. The release
// zone's bound is conservative by construction (the bound's half-width is one standard
// uncertainty, and a captive store sits at its edge), so over-coverage is expected and only the
// side that would make the stated uncertainty lie is asserted: coverage per axis at or above the
// lower end of the band, mean NEES at or below its upper end (n_eff = gaps, as above). The same
// acceptance must reject an ejector bound too small for the scenario's stroke (x 0.3: 30 m/s^2,
// 6 rad/s^2), or it could not see the defect.
TEST(PoseTracker, ExtrapolatesHonestlyThroughTheReleaseAndTheEjectorStroke) {
  const int seeds = seeds_from_env();
  const PoseTrackerConfig product;
  PoseTrackerConfig small_bound = product;
  small_bound.ejector_accel_max_m_s2 *= 0.3;
  small_bound.ejector_angular_accel_max_rad_s2 *= 0.3;
  std::vector<TrackerVariant> variants = {{"product defaults", product, GapScores()},
                                          {"ejector bound x 0.3", small_bound, GapScores()}};
  uncertainty::ConsistencyAccumulator<3> solved_attitude;
  int gaps = 0;
  // Gaps from the captive store (0) to the stroke's end (70 ms), every exposure before fed.
  run_gaps(variants, seeds, GapPlacement{0.0, 0.07, 1000}, solved_attitude, gaps);
  EXPECT_GE(gaps, seeds - seeds / 100) << seeds - gaps << " of " << seeds << " seeds left out";
  const test::HonestyBounds band = test::derived_bounds(gaps, 3);
  std::printf(
      "%d seeds, %d gaps scored; one-sided acceptance: coverage >= %.4f, mean NEES <= %.3f\n",
      seeds, gaps, band.coverage_low, band.nees_high);
  for (const TrackerVariant& v : variants) {
    std::printf("  %s: %d extrapolated\n", v.name, v.scores.extrapolated);
    print_scores("position (x,y,z)", v.scores.position);
    print_scores("attitude (y,p,r)", v.scores.attitude);
    print_scores("position, >= 7 frames ahead", v.scores.position_long);
  }
  auto under_states = [&](const GapScores& g) {
    bool out = false;
    for (const auto* acc : {&g.position, &g.attitude}) {
      out = out || acc->mean_nees() > band.nees_high;
      for (int a = 0; a < 3; ++a)
        out = out || acc->coverage(a) < band.coverage_low;
    }
    return out;
  };
  const GapScores& g = variants[0].scores;
  for (int a = 0; a < 3; ++a) {
    EXPECT_GE(g.position.coverage(a), band.coverage_low) << "position axis " << a;
    EXPECT_GE(g.attitude.coverage(a), band.coverage_low) << "attitude axis " << a;
  }
  EXPECT_LE(g.position.mean_nees(), band.nees_high);
  EXPECT_LE(g.attitude.mean_nees(), band.nees_high);
  EXPECT_TRUE(under_states(variants[1].scores))
      << "an ejector bound of 30 m/s^2 passes against an 80 m/s^2 stroke: the test cannot see it";
}

// The FtiSample budget of an extrapolated sample (issue 13): the process noise is a budget entry
// of its own, so the five budget fields add up to the total position variance, and it is the
// closed form of the constant-velocity lever sigma_a tau (tau + dt) / 2 on each of 3 axes.
TEST(PoseTracker, ExtrapolatedBudgetAddsUpWithTheProcessNoiseInIt) {
  const sim::Scenario scenario = sim::load_scenario(test::scenario_path("store_separation"));
  const sim::Simulator sim(scenario, 23);
  PoseTrackerConfig config;
  config.accel_sigma_m_s2 = 12.5;  // not the default: the closed form must follow the setting
  config.angular_accel_sigma_rad_s2 = 3.0;
  config.ejector_duration_max_s = 0;  // free flight from the first motion on (release zone: above)
  ProcessorConfig processor_config;
  processor_config.pose_tracker = config;
  ExposureProcessor proc(sim.calibrated_rig(), sim.pylon_survey(), sim.store_survey(),
                         processor_config);
  const double frame_s = 1.0 / scenario.frame_rate_hz;
  const int k0 = static_cast<int>(std::ceil(0.1 / frame_s));  // after the ejector stroke
  // Rounding bound of sum(budget^2) - (u_x^2 + u_y^2 + u_z^2), both exactly equal in real
  // arithmetic (J C J^T is linear in C = sum of the sources): every field is one f32 rounding
  // (relative u = FLT_EPSILON / 2) of a double, except u_budget_extrinsic = hypotf of two rounded
  // floats (2u); squaring doubles a relative error. So |parts - total| <= (4u + 2u) total.
  const double rounding = 3.0 * FLT_EPSILON;
  time::TaiNs t_last = 0, t_previous = 0;
  int extrapolated = 0;
  for (int k = k0; k < k0 + kSolvedBefore + kHidden; ++k) {
    test::SimExposure in = test::make_exposure(sim, k);
    const bool hidden = k >= k0 + kSolvedBefore;
    if (hidden) hide_store_marks(in);
    const ExposureResult r = proc.process(in.exposure, in.ids);
    const bool did = r.extrapolated;  // the processor's own tracker, with `config`
    const msg::FtiSample& s = r.sample;
    if (!(s.status & msg::fti_status::kValid)) continue;  // past the gap
    const double total2 =
        double{s.u_x_m} * s.u_x_m + double{s.u_y_m} * s.u_y_m + double{s.u_z_m} * s.u_z_m;
    const double parts2 = double{s.u_budget_centroid_m} * s.u_budget_centroid_m +
                          double{s.u_budget_intrinsic_m} * s.u_budget_intrinsic_m +
                          double{s.u_budget_extrinsic_m} * s.u_budget_extrinsic_m +
                          double{s.u_budget_sync_m} * s.u_budget_sync_m +
                          double{s.u_budget_process_m} * s.u_budget_process_m;
    EXPECT_LE(std::abs(parts2 - total2), rounding * total2)
        << "k " << k << (did ? " extrapolated" : " solved") << ": parts/total " << parts2 / total2;
    if (!did) {
      ASSERT_FALSE(hidden);
      EXPECT_EQ(s.u_budget_process_m, 0.0f) << "a measured sample has no process noise";
      t_previous = t_last;
      t_last = r.reference_mid_tai_ns;
      continue;
    }
    ++extrapolated;
    const double tau = static_cast<double>(r.reference_mid_tai_ns - t_last) * 1e-9;
    const double dt = static_cast<double>(t_last - t_previous) * 1e-9;
    const double expected = config.accel_sigma_m_s2 * 0.5 * tau * (tau + dt) * std::sqrt(3.0);
    // One f32 rounding of the double result (relative FLT_EPSILON / 2), a factor 2 of margin.
    EXPECT_NEAR(s.u_budget_process_m, expected, FLT_EPSILON * expected)
        << "k " << k << " tau " << tau << " dt " << dt;
    if (extrapolated == 1 || extrapolated == 7)
      std::printf(
          "  tau %.2f ms: u_budget_process %.4f mm (closed form %.4f mm), parts/total "
          "%.9f, u_budget_process^2 / total %.3f\n",
          tau * 1e3, s.u_budget_process_m * 1e3, expected * 1e3, parts2 / total2,
          s.u_budget_process_m * double{s.u_budget_process_m} / total2);
  }
  // 20 ms gap at 2.5 ms per exposure: 8 extrapolated samples (7 if jitter moves the 8th past it).
  EXPECT_GE(extrapolated, 7);
}

// The stated mean acceleration is part of the prediction: solved poses on an exact trajectory
// p(t) = p0 + v t + mu t^2 / 2 (mu the configured mean) turning at a constant rate about a fixed
// axis are extrapolated exactly (the closed form of the truth, to rounding), for the default
// 1 g and for another test point's mean. Without the mean the error is mu tau (tau + dt) / 2.
TEST(PoseTracker, PredictionFollowsTheStatedMeanAcceleration) {
  const std::array<Vec3, 2> means = {PoseTrackerConfig{}.mean_accel_p_m_s2, Vec3(1.0, -2.0, 4.9)};
  for (const Vec3& mu : means) {
    PoseTrackerConfig config;
    config.mean_accel_p_m_s2 = mu;
    config.ejector_duration_max_s = 0;  // free flight once the store moves (v_z = 4 m/s)
    PoseTracker tracker(uncertainty::CalibrationFactors{}, config);
    match::BodyMotion store;
    const Vec3 p0(0.1, -0.05, 0.3), v(0.5, 0.2, 4.0), w(0.05, 0.6, 0.1);
    const auto truth = [&](double t) {
      geometry::Transform T = geometry::Transform::Identity();
      T.linear() = geometry::rotation_from_rotvec(w * t);
      T.translation() = p0 + v * t + 0.5 * mu * t * t;
      return T;
    };
    constexpr time::TaiNs kStartNs = 1'000'000'000, kFrameNs = 2'500'000;
    for (int k = 0; k < 6; ++k) {
      ExposureResult r;
      r.reference_mid_tai_ns = kStartNs + k * kFrameNs;
      const geometry::Transform T_true = truth(static_cast<double>(k * kFrameNs) * 1e-9);
      if (k < 2) {  // two solved poses give the velocity
        r.T_p_s.valid = true;
        r.T_p_s.T = T_true;
        EXPECT_FALSE(tracker.update(r, store));
        continue;
      }
      ASSERT_TRUE(tracker.update(r, store)) << "k " << k;
      const Vec3 dp = r.T_p_s_extrapolated.translation() - T_true.translation();
      const double dphi = geometry::rotvec_from_rotation(r.T_p_s_extrapolated.linear() *
                                                         T_true.linear().transpose())
                              .norm();
      for (int a = 0; a < 3; ++a)
        EXPECT_NEAR(dp(a), 0.0, 1e-12) << "k " << k << " axis " << a;
      EXPECT_LT(dphi, 1e-12) << "k " << k;
    }
  }
}

// Before the store's first motion (a captive store: two solved poses at rest) the prediction
// carries the release zone's mean, the midpoint of [0, ejector_accel_max] along z_p, and its
// process budget is the closed form of the zone's spread: per axis (aero, aero, hypot(a_max / 2,
// aero)) times the lever tau (tau + dt) / 2. Once the store has moved for longer than
// ejector_duration_max_s the free-flight mean and spread return.
TEST(PoseTracker, ReleaseZoneMeanAndSpreadUntilFreeFlight) {
  PoseTrackerConfig config;
  PoseTracker tracker(uncertainty::CalibrationFactors{}, config);
  match::BodyMotion store;
  constexpr time::TaiNs kStartNs = 1'000'000'000, kFrameNs = 2'500'000;
  const Vec3 p0(0.1, -0.05, 0.3);
  auto solved = [&](int k, const Vec3& p) {
    ExposureResult r;
    r.reference_mid_tai_ns = kStartNs + k * kFrameNs;
    r.T_p_s.valid = true;
    r.T_p_s.T.translation() = p;
    EXPECT_FALSE(tracker.update(r, store));
  };
  auto predicted = [&](int k) {
    ExposureResult r;
    r.reference_mid_tai_ns = kStartNs + k * kFrameNs;
    EXPECT_TRUE(tracker.update(r, store)) << "k " << k;
    return r;
  };
  solved(0, p0);
  solved(1, p0);
  const double dt = 2.5e-3, tau = 2.5e-3, lever = 0.5 * tau * (tau + dt);
  const double half = 0.5 * config.ejector_accel_max_m_s2, aero = config.accel_sigma_m_s2;
  ExposureResult r = predicted(2);
  const Vec3 dp = r.T_p_s_extrapolated.translation() - p0;
  EXPECT_NEAR(dp.x(), 0.0, 1e-15);
  EXPECT_NEAR(dp.y(), 0.0, 1e-15);
  EXPECT_NEAR(dp.z(), half * lever, 1e-15);
  const auto i_proc = static_cast<size_t>(uncertainty::index(uncertainty::Source::kProcess));
  const geometry::Mat3 C = r.cov_xyz_ypr_by_source[i_proc].topLeftCorner<3, 3>();
  EXPECT_NEAR(std::sqrt(C(0, 0)), aero * lever, 1e-12 * aero * lever);
  EXPECT_NEAR(std::sqrt(C(2, 2)), std::hypot(half, aero) * lever, 1e-12 * half * lever);
  EXPECT_EQ(tracker.counters().extrapolated_in_release_zone, 1u);
  // The store moves away (0.01 m per frame: 4 m/s, no centroid covariance: any motion is
  // significant) at k = 3; free flight from 80 ms later (k = 3 + 32 = 35).
  solved(3, p0 + Vec3(0, 0, 0.01));
  solved(4, p0 + Vec3(0, 0, 0.02));
  predicted(5);
  EXPECT_EQ(tracker.counters().extrapolated_in_release_zone, 2u);
  solved(36, p0 + Vec3(0, 0, 0.33));
  solved(37, p0 + Vec3(0, 0, 0.34));
  r = predicted(38);
  EXPECT_EQ(tracker.counters().extrapolated_in_release_zone, 2u);
  const Vec3 p37 = p0 + Vec3(0, 0, 0.34);
  EXPECT_NEAR(r.T_p_s_extrapolated.translation().z(),
              p37.z() + 0.01 + config.mean_accel_p_m_s2.z() * lever, 1e-12);
}

// Issue 29: each body has one motion state, the matcher's BodyMotion. The processor's solved
// poses are recorded there (the same poses, time and order), the extrapolation reads them, and
// reset_tracking() forgets the filter and the solved poses together.
TEST(PoseTracker, TheStoresOneMotionStateIsTheMatchers) {
  const sim::Scenario scenario = sim::load_scenario(test::scenario_path("store_separation"));
  const sim::Simulator sim(scenario, 23);
  ExposureProcessor proc(sim.calibrated_rig(), sim.pylon_survey(), sim.store_survey(),
                         ProcessorConfig{});
  std::vector<ExposureResult> solved;
  for (int k = 60; k < 62; ++k) {
    const test::SimExposure in = test::make_exposure(sim, k);
    solved.push_back(proc.process(in.exposure, in.ids));
    ASSERT_TRUE(solved.back().T_p_s.valid) << "k " << k;
  }
  const match::BodyMotion& store = proc.matcher().motion(ExposureProcessor::kStoreBody);
  EXPECT_EQ(store.last_solved.t_ns, solved[1].reference_mid_tai_ns);
  EXPECT_TRUE(store.last_solved.pose.T.isApprox(solved[1].T_p_s.T, 0.0));
  EXPECT_EQ(store.last_solved.pose.cov, solved[1].T_p_s.cov);
  EXPECT_EQ(store.previous_solved.t_ns, solved[0].reference_mid_tai_ns);
  EXPECT_TRUE(store.previous_solved.pose.T.isApprox(solved[0].T_p_s.T, 0.0));
  EXPECT_TRUE(store.last_world.T.isApprox(solved[1].T_w_s.T, 0.0));
  EXPECT_TRUE(proc.matcher()
                  .motion(ExposureProcessor::kPylonBody)
                  .last_world.T.isApprox(solved[1].T_w_p.T, 0.0));

  test::SimExposure hidden = test::make_exposure(sim, 62);
  hide_store_marks(hidden);
  ExposureProcessor kept = proc;
  EXPECT_TRUE(kept.process(hidden.exposure, hidden.ids).extrapolated);
  proc.reset_tracking();
  for (int b : {ExposureProcessor::kPylonBody, ExposureProcessor::kStoreBody}) {
    EXPECT_FALSE(proc.matcher().motion(b).filter.valid);
    EXPECT_FALSE(proc.matcher().motion(b).last_world.valid);
    EXPECT_FALSE(proc.matcher().motion(b).last_solved.valid);
    EXPECT_FALSE(proc.matcher().motion(b).previous_solved.valid);
  }
  const ExposureResult r = proc.process(hidden.exposure, hidden.ids);
  EXPECT_FALSE(r.extrapolated);
  EXPECT_FALSE(r.sample.status & msg::fti_status::kValid);
}

TEST(PoseTracker, NoVelocityNoExtrapolation) {
  const sim::Scenario scenario = sim::load_scenario(test::scenario_path("store_separation"));
  const sim::Simulator sim(scenario, 17);
  ExposureProcessor proc(sim.calibrated_rig(), sim.pylon_survey(), sim.store_survey(),
                         ProcessorConfig{});
  const PoseTracker& tracker = proc.pose_tracker();
  // One solved exposure only: no velocity, so the next unsolved one is not extrapolated.
  test::SimExposure in = test::make_exposure(sim, 60);
  ExposureResult r = proc.process(in.exposure, in.ids);
  EXPECT_FALSE(r.extrapolated);
  in = test::make_exposure(sim, 61);
  hide_store_marks(in);
  r = proc.process(in.exposure, in.ids);
  EXPECT_FALSE(r.extrapolated);
  EXPECT_FALSE(r.sample.status & msg::fti_status::kValid);
  EXPECT_FALSE(r.sample.status & msg::fti_status::kExtrapolated);
  EXPECT_EQ(tracker.counters().not_extrapolated, 1u);
  EXPECT_EQ(tracker.counters().solved, 1u);
  PoseTrackerConfig bad;
  bad.max_velocity_baseline_s = 0;
  EXPECT_THROW(PoseTracker(proc.factors(), bad), std::invalid_argument);
}

}  // namespace
}  // namespace storetrack::pipeline
