// End-to-end honesty (issue 10): the product's promise as a test. Where test_uncertainty.cpp
// feeds the processor the simulator's true mark ids and fast-mode observations whose noise IS
// the stated sigma, this runs what the instrument runs: the simulator's rendered frames (shot
// and read noise, quantisation, blur) -> the camera unit's centroider (estimation/centroid, the
// unit's default configuration; its own sigma_px) -> MarkObservations as the unit fills them ->
// the host's ExposureProcessor with its MarkMatcher (host/match: acquisition from the
// installation survey's prior poses, tracking) -> triangulation, rigid-body checks and the pose
// with its GUM uncertainty. Not exercised here (tools/testpoint runs them): the link, the
// aligner and the unit's trigger pairing; the exposure time stamps are those the unit reports.
// One shortcut: after the release the store's track at the window's first exposure is given to
// the matcher as a prior pose (set_window_prior) instead of tracking it from the carriage
// (STORETRACK_E2E_STORE_TRACK=start does that, ~40x the CPU).
//
// Independent unit: the calibration draw. The calibration and survey errors (drawn once per
// simulator seed) dominate the pose budget and are shared by every exposure of a draw, so the
// draws, not the samples, are the effective sample size; ONE exposure per draw is scored (after
// kWarmup exposures that let the matcher acquire and the processor estimate velocities), which
// makes the scored samples independent and the count inside a k = 2 interval Binomial(n, 95.45 %)
// exactly, and the summed 6-DoF NEES chi-square(6 n) for an honest instrument.
//
// Acceptance (issue 10): per axis of the store position and attitude, k = 2 coverage within
// 93-97 %; mean 6-DoF NEES within 10 % of 6; widened to the alpha = 0.001-per-side binomial and
// chi-square intervals of the draws actually scored where those are wider (the reduced CI form).
// Draws where the host gives no pose are counted: at most the binomial upper bound of a 1 %
// refusal rate, and the coverage with them counted as misses is printed.
//
// CI (Release): 150 draws per scene; STORETRACK_E2E_DRAWS=N for the full form (docs/evaluation.md,
// "End-to-end honesty": at 1500 draws the binomial interval, 93.7-97.0 %, lies inside the band).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "honesty_bounds.hpp"
#include "sim_exposure.hpp"
#include "storetrack/centroid/centroider.hpp"
#include "storetrack/match/mark_matcher.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack {
namespace {

using geometry::Vec3;
using Vec6 = Eigen::Matrix<double, 6, 1>;

#ifdef STORETRACK_SANITIZE
constexpr int kDefaultDraws = 20;  // ASan/UBSan: a smoke run of the chain
#else
constexpr int kDefaultDraws = 150;
#endif
constexpr int kMinDrawsForPower = 100;
constexpr int kWarmup = 2;                   // exposures before the scored one
constexpr std::uint64_t kSeedBase = 700000;  // not the seeds of the other honesty tests
constexpr double kMaxRefusalRate = 0.01;
// The host's defaults: installation survey 1 mm per axis (tools/sim_setup.py), prior sigma 5 mm
// (identifier.initial_marks_sigma_m).
constexpr double kInitialMarksNoiseM = 1e-3;
constexpr double kInitialMarksSigmaM = 5e-3;

int draws_from_environment() {
  const char* s = std::getenv("STORETRACK_E2E_DRAWS");
  const int n = s ? std::atoi(s) : 0;
  return n > 0 ? n : kDefaultDraws;
}

/// One camera unit: the firmware centroider on the simulator's rendered frames.
class RenderingUnit {
 public:
  RenderingUnit(const sim::Simulator& sim, int camera_index)
      : sim_(sim),
        camera_index_(camera_index),
        intrinsics_(sim.true_rig().cameras[static_cast<size_t>(camera_index)].model.intrinsics()),
        centroider_(centroid::CentroidConfig{}, intrinsics_.width, intrinsics_.height),
        image_(static_cast<size_t>(intrinsics_.width) * static_cast<size_t>(intrinsics_.height)),
        blobs_(msg::kMaxMarks) {}

  /// Renders exposure k, centroids it and fills the observation as storetrack-unit does
  /// (firmware/app/src/unit_runner.cpp, "The message"); false when the centroider refused it.
  bool observe(int k, msg::MarkObservations& out) {
    sim_.render_into(k, camera_index_, image_.data(), intrinsics_.width, renderer_);
    const sim::ExposureTiming t = sim_.exposure_timing(k, camera_index_);
    frame::FrameView view;
    view.pixels = image_.data();
    view.width = intrinsics_.width;
    view.height = intrinsics_.height;
    view.stride_bytes = intrinsics_.width;
    view.sequence = t.trigger_seq;
    view.timestamp_mono_ns = t.reported_start_mono_ns;
    view.exposure_ns = t.exposure_ns;
    const int n = centroider_.process(view, blobs_);
    if (n < 0) return false;
    const auto& cam = sim_.scenario().cameras[static_cast<size_t>(camera_index_)];
    out = msg::MarkObservations{};
    out.unit_id = static_cast<std::uint8_t>(cam.unit_id);
    out.camera_id = static_cast<std::uint8_t>(cam.camera_id);
    out.trigger_seq = t.trigger_seq;
    out.exposure_start_tai_ns = t.reported_start_tai_ns;
    out.exposure_start_mono_ns = t.reported_start_mono_ns;
    out.exposure_duration_ns = t.exposure_ns;
    out.clock_state = static_cast<std::uint8_t>(sim_.scenario().clock_state);
    out.mark_count = static_cast<std::uint8_t>(n);
    for (int i = 0; i < n; ++i) {
      const centroid::Blob& b = blobs_[static_cast<size_t>(i)];
      msg::MarkObservation& m = out.marks[static_cast<size_t>(i)];
      m.x_px = static_cast<float>(b.x_px);
      m.y_px = static_cast<float>(b.y_px);
      m.sigma_px = static_cast<float>(b.sigma_px);
      m.peak = static_cast<std::uint16_t>(std::clamp(b.peak_dn, 0.0f, 255.0f));
      m.diameter_px = b.diameter_px;
      m.flags = b.flags & msg::mark_flags::kAllKnown;
    }
    return true;
  }

 private:
  const sim::Simulator& sim_;
  int camera_index_;
  camera::Intrinsics intrinsics_;
  centroid::Centroider centroider_;
  sim::SpotRenderer renderer_;
  std::vector<std::uint8_t> image_;
  std::vector<centroid::Blob> blobs_;
};

/// The host's matcher set-up (storetrack-host set_prior_poses): prior poses fitted to the
/// installation survey's initial mark positions (exposure 0, 1 mm noise per axis). Returns the
/// store's prior covariance.
geometry::Mat6 set_installation_priors(const sim::Simulator& sim, std::mt19937_64& rng,
                                       pipeline::ExposureProcessor& proc) {
  std::normal_distribution<double> noise(0.0, kInitialMarksNoiseM);
  std::map<int, Vec3> initial;
  for (const sim::MarkTruth& mk : sim.truth(0).marks)
    initial[mk.id] = mk.p_w0 + Vec3(noise(rng), noise(rng), noise(rng));
  geometry::Mat6 cov = geometry::Mat6::Zero();
  for (const survey::RigidBodySurvey* body : {&sim.pylon_survey(), &sim.store_survey()}) {
    geometry::Transform T_w_b;
    EXPECT_TRUE(match::fit_body_pose(*body, initial, kInitialMarksSigmaM, T_w_b, cov));
    EXPECT_TRUE(proc.matcher().set_prior_pose(body->name, T_w_b, cov));
  }
  return cov;
}

/// The store's track at the first exposure of a window that starts after the release: the
/// matcher's acquisition path (a prior pose) with the installation prior's covariance, centred
/// on a draw from it about the true pose (as tests/host/match does). It stands in for tracking
/// every exposure from the carriage (StoreTrack::kFromStart does that: ~110 rendered
/// exposures per draw instead of 3); re-acquisition without a track is not what is scored here
/// (docs/evaluation.md: with rendered frames it is refused or wrong too often mid-separation).
void set_window_prior(const sim::Simulator& sim, int k, const geometry::Mat6& cov,
                      std::mt19937_64& rng, pipeline::ExposureProcessor& proc) {
  const sim::ExposureTruth t = sim.truth(k);
  const geometry::Transform T_w0_s = sim.T_w0_w_at(t.reference_tai_ns) * t.T_w_p * t.T_p_s;
  std::normal_distribution<double> g(0.0, 1.0);
  Vec6 delta;
  for (int i = 0; i < 6; ++i)
    delta(i) = std::sqrt(cov(i, i)) * g(rng);
  EXPECT_TRUE(proc.matcher().set_prior_pose(sim.store_survey().name,
                                            geometry::perturb_left(T_w0_s, delta), cov));
}

/// How the store's track reaches the scored window (STORETRACK_E2E_STORE_TRACK): "window"
/// (default, set_window_prior), "start" (every exposure from the carriage), "reacquire" (no
/// track: the matcher's re-acquisition in the region; a diagnosis, docs/evaluation.md).
enum class StoreTrack { kWindowPrior, kFromStart, kReacquire };

StoreTrack store_track_from_environment() {
  const char* s = std::getenv("STORETRACK_E2E_STORE_TRACK");
  const std::string v = s ? s : "window";
  if (v == "start") return StoreTrack::kFromStart;
  if (v == "reacquire") return StoreTrack::kReacquire;
  EXPECT_EQ(v, "window") << "STORETRACK_E2E_STORE_TRACK: window, start or reacquire";
  return StoreTrack::kWindowPrior;
}

/// The host's store_region (identifier.store_region) for a separation: within 30 deg of the
/// carriage attitude, 1.5 m aft to 0.1 m forward, 0.5 m to either side, 0.1 m up to 5 m down
/// (the envelope docs/matching.md and test_mark_matcher use). Lets the matcher acquire the
/// store wherever the scored exposure falls, as a host started mid-separation would.
match::BodyRegion separation_region(const sim::Simulator& sim) {
  match::BodyRegion r;
  r.reference_body = sim.pylon_survey().name;
  r.T_ref_b_nominal = sim.truth(0).T_p_s;
  r.max_rotation_rad = 30.0 * M_PI / 180.0;
  r.min_offset_m = Vec3(-1.5, -0.5, -0.1);
  r.max_offset_m = Vec3(0.1, 0.5, 5.0);
  return r;
}

/// The store pose's consistency with its stated covariance scaled by s^2 (u scaled by s).
struct PoseScore {
  explicit PoseScore(double scale = 1) : u_scale(scale) {}
  double u_scale;
  uncertainty::ConsistencyAccumulator<3> position, attitude;
  uncertainty::ConsistencyAccumulator<6> pose;  ///< (x, y, z, yaw, pitch, roll) jointly
  void add(const Vec6& e, const geometry::Mat6& cov) {
    const geometry::Mat6 c = u_scale * u_scale * cov;
    position.add(e.head<3>(), c.topLeftCorner<3, 3>());
    attitude.add(e.tail<3>(), c.bottomRightCorner<3, 3>());
    pose.add(e, c);
  }
  double coverage(int axis) const {
    return axis < 3 ? position.coverage(axis) : attitude.coverage(axis - 3);
  }
  bool within(const test::HonestyBounds& b) const {
    bool ok = pose.mean_nees() >= b.nees_low && pose.mean_nees() <= b.nees_high;
    for (int a = 0; a < 6; ++a)
      ok = ok && coverage(a) >= b.coverage_low && coverage(a) <= b.coverage_high;
    return ok;
  }
};

// The host's stated uncertainty as it is, and two wrong ones the acceptance must reject (its
// power at the draws run: u understated by 30 %, overstated by 40 %).
constexpr std::array<double, 3> kUncertaintyScales{1.0, 0.7, 1.4};

struct Tally {
  uncertainty::ConsistencyAccumulator<3> marks;
  std::array<PoseScore, kUncertaintyScales.size()> store{PoseScore(kUncertaintyScales[0]),
                                                         PoseScore(kUncertaintyScales[1]),
                                                         PoseScore(kUncertaintyScales[2])};
  std::array<int, 6> inside_with_refusals{};  ///< refused draws counted as misses
  int draws = 0, refused = 0, ids = 0, wrong_ids = 0;
};

/// One exposure as the host's aligner hands it over: every unit's observation of exposure k.
/// STORETRACK_E2E_OBSERVATIONS=fast replaces the frames and the centroider by the simulator's
/// fast mode (a diagnosis: which of the two a failure comes from).
pipeline::AlignedExposure rendered_exposure(const sim::Simulator& sim,
                                            std::vector<RenderingUnit>& units, int k) {
  static const bool fast = [] {
    const char* v = std::getenv("STORETRACK_E2E_OBSERVATIONS");
    return v && std::string(v) == "fast";
  }();
  pipeline::AlignedExposure e;
  for (int c = 0; c < static_cast<int>(units.size()); ++c) {
    msg::MarkObservations obs;
    if (fast) sim.observe(k, c, obs);
    if (fast || units[static_cast<size_t>(c)].observe(k, obs)) e.cameras.push_back(obs);
  }
  if (!e.cameras.empty()) {
    e.trigger_seq = e.cameras[0].trigger_seq;
    e.exposure_mid_tai_ns = pipeline::exposure_mid_tai_ns(e.cameras[0]);
  }
  return e;
}

/// A mark 10 cm from its truth was given another mark's id (the store's marks are >= 0.2 m
/// apart, a stated u is ~1 mm).
constexpr double kWrongIdErrorM = 0.1;

/// The scored exposure against the simulator's truth.
void score(const sim::Simulator& sim, const pipeline::ExposureResult& r, Tally& tally) {
  ++tally.draws;
  const time::TaiNs t = r.reference_mid_tai_ns;
  for (const pipeline::MarkResult& m : r.marks) {
    if (m.excluded) continue;
    ++tally.ids;
    const Vec3 e = test::true_mark_in_host_world(sim, m.id, t) - m.p_w;
    if (e.norm() > kWrongIdErrorM) ++tally.wrong_ids;
    tally.marks.add(e, m.cov_w);
  }
  if (!r.T_p_s.valid) {
    ++tally.refused;
    return;
  }
  const geometry::Transform T_true = sim.T_p_s_at(t);
  Vec6 e;
  e.head<3>() = T_true.translation() - r.T_p_s.T.translation();
  const Vec3 ypr_true = geometry::ypr_from_rotation(T_true.linear());
  for (int a = 0; a < 3; ++a)
    e(3 + a) = std::remainder(ypr_true(a) - r.xyz_ypr(3 + a), 2 * M_PI);
  for (PoseScore& score : tally.store)
    score.add(e, r.cov_xyz_ypr);
  for (int a = 0; a < 6; ++a)
    if (std::abs(e(a)) <= 2.0 * std::sqrt(r.cov_xyz_ypr(a, a)))
      ++tally.inside_with_refusals[static_cast<size_t>(a)];
}

/// One line per draw (STORETRACK_E2E_VERBOSE): what the matcher did.
void print_draw(const sim::Simulator& sim, int draw, int k, const pipeline::ExposureResult& r,
                const match::MatchCounters& mc) {
  int store_ids = 0, wrong_ids = 0;
  for (const pipeline::MarkResult& m : r.marks) {
    store_ids += m.id >= 100 && m.id < 200;
    if (!m.excluded &&
        (test::true_mark_in_host_world(sim, m.id, r.reference_mid_tai_ns) - m.p_w).norm() >
            kWrongIdErrorM)
      ++wrong_ids;
  }
  std::printf(
      "draw %d k %d: pose %d, store ids %d (wrong %d), re-acquisitions %llu (accepted %llu, "
      "ambiguous %llu), acquisitions %llu\n",
      draw, k, r.T_p_s.valid, store_ids, wrong_ids,
      static_cast<unsigned long long>(mc.reacquisition_attempted),
      static_cast<unsigned long long>(mc.reacquisition_accepted),
      static_cast<unsigned long long>(mc.reacquisition_ambiguous),
      static_cast<unsigned long long>(mc.acquisitions));
}

/// Draw `draw`: the host set up as storetrack-host sets it up, the exposures up to the scored
/// one processed, the scored one scored.
void run_draw(const sim::Scenario& scenario, int draw, Tally& tally) {
  const sim::Simulator sim(scenario, kSeedBase + static_cast<std::uint64_t>(draw));
  std::mt19937_64 rng(kSeedBase + static_cast<std::uint64_t>(draw));
  pipeline::ExposureProcessor proc(sim.calibrated_rig(), sim.pylon_survey(), sim.store_survey(),
                                   pipeline::ProcessorConfig{});
  const geometry::Mat6 prior_cov = set_installation_priors(sim, rng, proc);
  ASSERT_TRUE(proc.matcher().set_region(sim.store_survey().name, separation_region(sim)));
  std::vector<RenderingUnit> units;
  units.reserve(static_cast<size_t>(sim.num_cameras()));
  for (int c = 0; c < sim.num_cameras(); ++c)
    units.emplace_back(sim, c);
  std::uniform_int_distribution<int> pick(kWarmup, sim.num_exposures() - 1);
  const int k_scored = pick(rng);
  const StoreTrack track = store_track_from_environment();
  const int k_first = track == StoreTrack::kFromStart ? 0 : k_scored - kWarmup;
  const bool store_moved =
      (sim.truth(k_first).T_p_s.translation() - sim.truth(0).T_p_s.translation()).norm() > 1e-3;
  if (track == StoreTrack::kWindowPrior && store_moved)
    set_window_prior(sim, k_first, prior_cov, rng, proc);
  pipeline::ExposureResult r;
  for (int k = k_first; k <= k_scored; ++k) {
    const pipeline::AlignedExposure e = rendered_exposure(sim, units, k);
    ASSERT_FALSE(e.cameras.empty()) << "draw " << draw << ", exposure " << k;
    r = proc.process(e);
  }
  if (std::getenv("STORETRACK_E2E_VERBOSE"))
    print_draw(sim, draw, k_scored, r, proc.matcher().counters());
  score(sim, r, tally);
}

void print(const char* what, const auto& acc) {
  std::printf("  %-16s n=%6lld coverage(k=2) %.2f %.2f %.2f %%  mean NEES %.3f\n", what,
              static_cast<long long>(acc.count()), 100 * acc.coverage(0), 100 * acc.coverage(1),
              100 * acc.coverage(2), acc.mean_nees());
}

TEST(EndToEndHonesty, RenderedFramesCentroiderMatcherHost) {
  const std::string scene = STORETRACK_HONESTY_SCENE;
  const sim::Scenario scenario = sim::load_scenario(test::scenario_path(scene));
  const int draws = draws_from_environment();
  Tally tally;
  for (int d = 0; d < draws; ++d) {
    run_draw(scenario, d, tally);
    if (HasFatalFailure()) return;
  }
  const PoseScore& stated = tally.store[0];
  const int scored = static_cast<int>(stated.pose.count());
  std::printf(
      "scene %s: %d draws (one scored exposure each), pose refused in %d, %d ids scored (%d of "
      "them > %.0f cm from their truth: wrong ids)\n",
      scene.c_str(), tally.draws, tally.refused, tally.ids, tally.wrong_ids, kWrongIdErrorM * 100);
  print("marks (x,y,z)", tally.marks);
  print("T_p_s (x,y,z)", stated.position);
  print("T_p_s (y,p,r)", stated.attitude);
  std::printf("  T_p_s 6-DoF      n=%6d mean NEES %.3f\n", scored, stated.pose.mean_nees());
  std::printf("  refused draws counted as misses: coverage x y z yaw pitch roll");
  for (int a = 0; a < 6; ++a)
    std::printf(" %.2f", 100.0 * tally.inside_with_refusals[static_cast<size_t>(a)] / tally.draws);
  std::printf(" %%\n");

  ASSERT_EQ(scored + tally.refused, draws);
  const std::int64_t max_refused =
      uncertainty::binomial_interval(draws, kMaxRefusalRate, test::kAlphaPerSide).high;
  EXPECT_LE(tally.refused, max_refused) << "refusal rate above " << kMaxRefusalRate;
  ASSERT_GT(scored, 0);
  const test::HonestyBounds required{0.93, 0.97, 6.0 * 0.9, 6.0 * 1.1};
  const test::HonestyBounds band = test::widened(required, test::derived_bounds(scored, 6));
  std::printf(
      "  acceptance (%d scored draws): coverage [%.2f, %.2f] %%, 6-DoF mean NEES [%.3f, %.3f], "
      "refused <= %lld\n",
      scored, 100 * band.coverage_low, 100 * band.coverage_high, band.nees_low, band.nees_high,
      static_cast<long long>(max_refused));
  static const char* const kAxis[6] = {"x", "y", "z", "yaw", "pitch", "roll"};
  for (int a = 0; a < 6; ++a) {
    EXPECT_GE(stated.coverage(a), band.coverage_low) << "store " << kAxis[a];
    EXPECT_LE(stated.coverage(a), band.coverage_high) << "store " << kAxis[a];
  }
  EXPECT_GE(stated.pose.mean_nees(), band.nees_low);
  EXPECT_LE(stated.pose.mean_nees(), band.nees_high);
  // Power: the same samples with a wrong stated u must fail the band.
  for (size_t i = 1; i < tally.store.size(); ++i) {
    const PoseScore& wrong = tally.store[i];
    std::printf("  u x %.1f: coverage", wrong.u_scale);
    for (int a = 0; a < 6; ++a)
      std::printf(" %.2f", 100 * wrong.coverage(a));
    std::printf(" %%, 6-DoF mean NEES %.3f: %s\n", wrong.pose.mean_nees(),
                wrong.within(band) ? "ACCEPTED (the band cannot tell)" : "rejected");
    // Asserted from the CI form's size up (the sanitizer tree's 20 draws are a smoke run).
    if (scored >= kMinDrawsForPower) {
      EXPECT_FALSE(wrong.within(band)) << "u scaled by " << wrong.u_scale << " passes the band";
    }
  }
}

}  // namespace
}  // namespace storetrack
