// Issue 11, "the store pose coverage stays honest (uncertainty grows where cameras are
// missing)": the honesty Monte Carlo of test_uncertainty.cpp with cameras removed from the
// exposure (as the aligner delivers it when a camera misses its deadline). Every camera subset
// that can still triangulate is scored on the SAME calibration draws: all 4 cameras (control),
// each single camera removed, and each pair of cameras left.
//
// Independence: the calibration and survey errors dominate the budget and are common to all
// marks and exposures of a draw (one simulator seed), so a draw gives ONE sample per quantity:
// one mark picked at random among the non-excluded marks, and the store pose. With n draws the
// number of samples inside k = 2 is Binomial(n, 0.9545) per axis when the stated uncertainty
// is honest (first-order Gaussian), and n * mean NEES of 3-D vectors is chi-square(3 n).
// Both are asserted two-sided at alpha = 0.001 per side. The subsets share the draws, so their
// verdicts are correlated with each other, not within one subset.
//
// The static scene cannot be used: without any one camera its store marks are too few or
// collinear for a pose. SingleCameraRemoved: 800 draws in CI (~41 s CPU in Release), full form
// STORETRACK_HONESTY_DRAWS=4000. TwoCamerasLeft: its full form, 4000 draws (~125 s CPU), also in
// CI: at 800 and 1500 draws the marks' y coverage of cameras 1+2 sits just above its bound
// (over-coverage, open, docs/uncertainty.md), and the full form resolves the attitude NEES
// defect it guards most surely. STORETRACK_HONESTY_DRAWS sets both; the bounds are derived for the
// samples each subset has.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "honesty_bounds.hpp"
#include "sim_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack {
namespace {

using geometry::Vec3;

using test::kAlphaPerSide;
using test::kCoverageK2;
// Below this a subset's binomial interval is too wide to say anything (at n = 150: 90-99 %).
constexpr int kMinScoredSamples = 150;
// Exposures per draw: the first gives the tracker the marks' velocities (synchronisation
// term), the second, at a random instant of the scenario, is evaluated.
constexpr int kExposuresPerDraw = 2;

// sanitizer_draws: the sanitizer tree's count (ASan/UBSan ~10x slower); 150 where it is scored.
int draws_from_environment(int release_draws, int sanitizer_draws = kMinScoredSamples) {
#ifdef STORETRACK_SANITIZE
  int draws = sanitizer_draws;
  (void)release_draws;
#else
  int draws = release_draws;
  (void)sanitizer_draws;
#endif
  if (const char* env = std::getenv("STORETRACK_HONESTY_DRAWS")) draws = std::atoi(env);
  return std::max(draws, 50);
}

struct Subset {
  Subset(std::string n, std::uint32_t mask) : name(std::move(n)), removed_mask(mask) {}
  std::string name;
  std::uint32_t removed_mask = 0;  ///< bit i: rig camera i removed
  uncertainty::ConsistencyAccumulator<3> mark;
  uncertainty::ConsistencyAccumulator<3> store_position;
  uncertainty::ConsistencyAccumulator<3> store_attitude;
  int no_mark = 0, no_pose = 0;  ///< draws left out (counted, printed)
  /// Observations the processor did not use (border-cut or merged blobs; counted, printed).
  std::uint64_t rejected_by_flags = 0;
};

std::vector<Subset> single_camera_removed(int num_cameras) {
  std::vector<Subset> out;
  out.emplace_back("all cameras", 0);  // control: the machinery of test_uncertainty.cpp
  for (int c = 0; c < num_cameras; ++c)
    out.emplace_back("without camera " + std::to_string(c), 1u << c);
  return out;
}

std::vector<Subset> two_cameras_left(int num_cameras) {
  std::vector<Subset> out;
  for (int a = 0; a < num_cameras; ++a)
    for (int b = a + 1; b < num_cameras; ++b) {
      const std::uint32_t keep = (1u << a) | (1u << b);
      out.emplace_back("cameras " + std::to_string(a) + "+" + std::to_string(b) + " only",
                       ((1u << num_cameras) - 1) & ~keep);
    }
  return out;
}

// The exposure as the aligner delivers it without the removed cameras.
test::SimExposure without_cameras(const test::SimExposure& full, std::uint32_t removed_mask,
                                  const camera::RigCalibration& rig) {
  test::SimExposure out;
  out.exposure = full.exposure;
  out.exposure.cameras.clear();
  for (size_t e = 0; e < full.exposure.cameras.size(); ++e) {
    const int id = full.exposure.cameras[e].camera_id;
    int slot = -1;
    for (size_t s = 0; s < rig.cameras.size(); ++s)
      if (rig.cameras[s].camera_id == id) slot = static_cast<int>(s);
    if (slot >= 0 && (removed_mask >> slot) & 1u) continue;
    out.exposure.cameras.push_back(full.exposure.cameras[e]);
    out.ids.push_back(full.ids[e]);
  }
  out.exposure.missing_camera_mask = removed_mask;
  out.exposure.exposure_mid_tai_ns = pipeline::exposure_mid_tai_ns(out.exposure.cameras[0]);
  for (const msg::MarkObservations& obs : out.exposure.cameras)
    out.exposure.exposure_mid_tai_ns =
        std::min(out.exposure.exposure_mid_tai_ns, pipeline::exposure_mid_tai_ns(obs));
  return out;
}

void score(const sim::Simulator& sim, const pipeline::ExposureResult& r, std::mt19937_64& pick,
           Subset& s) {
  const time::TaiNs t = r.reference_mid_tai_ns;
  std::vector<const pipeline::MarkResult*> marks;
  for (const pipeline::MarkResult& m : r.marks)
    if (!m.excluded) marks.push_back(&m);
  if (marks.empty()) {
    ++s.no_mark;
  } else {
    std::uniform_int_distribution<size_t> one(0, marks.size() - 1);
    const pipeline::MarkResult& m = *marks[one(pick)];
    s.mark.add(test::true_mark_in_host_world(sim, m.id, t) - m.p_w, m.cov_w);
  }
  if (!r.T_p_s.valid) {
    ++s.no_pose;
    return;
  }
  const geometry::Transform T_true = sim.T_p_s_at(t);
  const Vec3 ypr_true = geometry::ypr_from_rotation(T_true.linear());
  Vec3 e_att;
  for (int a = 0; a < 3; ++a)
    e_att(a) = std::remainder(ypr_true(a) - r.xyz_ypr(3 + a), 2 * M_PI);
  s.store_position.add(T_true.translation() - r.T_p_s.T.translation(),
                       r.cov_xyz_ypr.topLeftCorner<3, 3>());
  s.store_attitude.add(e_att, r.cov_xyz_ypr.bottomRightCorner<3, 3>());
}

void run_draws(const std::string& scenario_name, int draws, std::vector<Subset>& subsets) {
  const sim::Scenario scenario = sim::load_scenario(test::scenario_path(scenario_name));
  std::mt19937_64 pick(4242);
  for (int d = 0; d < draws; ++d) {
    // Seeds disjoint from test_uncertainty.cpp's (1000 + run): other calibration draws.
    const sim::Simulator sim(scenario, 500000 + static_cast<std::uint64_t>(d));
    const camera::RigCalibration rig = sim.calibrated_rig();
    std::uniform_int_distribution<int> start(0, sim.num_exposures() - kExposuresPerDraw);
    const int k0 = start(pick);
    std::vector<test::SimExposure> full;
    for (int k = k0; k < k0 + kExposuresPerDraw; ++k)
      full.push_back(test::make_exposure(sim, k));
    for (Subset& s : subsets) {
      pipeline::ExposureProcessor proc(rig, sim.pylon_survey(), sim.store_survey(),
                                       pipeline::ProcessorConfig{});
      pipeline::ExposureResult r;
      for (const test::SimExposure& f : full) {
        const test::SimExposure in = without_cameras(f, s.removed_mask, rig);
        r = proc.process(in.exposure, in.ids);
      }
      s.rejected_by_flags += proc.matcher().counters().rejected_by_flags;
      score(sim, r, pick, s);
    }
  }
}

void expect_consistent(const std::string& subset, const char* what,
                       const uncertainty::ConsistencyAccumulator<3>& acc) {
  const std::int64_t n = acc.count();
  const test::HonestyBounds b = test::derived_bounds(n, 3);
  std::printf(
      "    %-14s n=%5lld inside(k=2) %5.1f %5.1f %5.1f %%  [%.1f, %.1f]  mean NEES %.3f "
      "[%.3f, %.3f]\n",
      what, static_cast<long long>(n), 100 * acc.coverage(0), 100 * acc.coverage(1),
      100 * acc.coverage(2), 100 * b.coverage_low, 100 * b.coverage_high, acc.mean_nees(),
      b.nees_low, b.nees_high);
  for (int a = 0; a < 3; ++a) {
    EXPECT_GE(acc.coverage(a), b.coverage_low) << subset << ", " << what << " axis " << a;
    EXPECT_LE(acc.coverage(a), b.coverage_high) << subset << ", " << what << " axis " << a;
  }
  EXPECT_GE(acc.mean_nees(), b.nees_low) << subset << ", " << what;
  EXPECT_LE(acc.mean_nees(), b.nees_high) << subset << ", " << what;
}

void run_and_expect(std::vector<Subset> subsets, int release_draws) {
  const int draws = draws_from_environment(release_draws);
  run_draws(STORETRACK_HONESTY_SCENE, draws, subsets);
  std::printf(
      "scene %s: %d independent calibration draws, one sample per draw and quantity; "
      "k=2 coverage %.2f %%, alpha %.3g per side\n",
      STORETRACK_HONESTY_SCENE, draws, 100 * kCoverageK2, kAlphaPerSide);
  for (const Subset& s : subsets) {
    std::printf(
        "  %s: left out %d draws without a mark, %d without a store pose; %llu border-cut or "
        "merged observations not used\n",
        s.name.c_str(), s.no_mark, s.no_pose, static_cast<unsigned long long>(s.rejected_by_flags));
    // Too few samples for a binomial test of coverage (the store outside the subset's view in
    // most draws, e.g. after separation): counted, not scored.
    if (s.store_position.count() < kMinScoredSamples) {
      std::printf("    store pose not scored: %lld samples < %d\n",
                  static_cast<long long>(s.store_position.count()), kMinScoredSamples);
      if (s.mark.count() >= kMinScoredSamples) expect_consistent(s.name, "mark (x,y,z)", s.mark);
      continue;
    }
    expect_consistent(s.name, "mark (x,y,z)", s.mark);
    expect_consistent(s.name, "T_p_s (x,y,z)", s.store_position);
    expect_consistent(s.name, "T_p_s (y,p,r)", s.store_attitude);
  }
}

// A camera lost (issue 11): the case of the network-fault runs.
TEST(UncertaintyHonestyMissingCamera, SingleCameraRemoved) {
  run_and_expect(single_camera_removed(4), 800);
}

// Two cameras left: the smallest rig that still triangulates. Before the processor rejected
// border-cut blobs given with ids (ExposureProcessor.BorderCutBlobIsNotUsedEvenWithGivenIds),
// the full form FAILED on the store attitude's mean NEES (cameras 1+3 3.48, 2+3 3.21 against
// upper bounds 3.27 / 3.15): the cut blobs' inward-pulled centroids (docs/uncertainty.md).
TEST(UncertaintyHonestyMissingCamera, TwoCamerasLeft) {
#ifdef STORETRACK_SANITIZE
  // Sanitizer tree: the pairs' code paths under ASan + UBSan, not scored, so 50 draws (the
  // least draws_from_environment gives; 150 took 13.5 s). Their statistics are asserted in
  // Release at 4000 draws: the 1+2 mark y coverage is about 96-97 % (conservative, open,
  // docs/uncertainty.md), and 150 draws (seeds 500000..500149) all landed inside, one above that
  // size's two-sided upper bound (149).
  std::vector<Subset> subsets = two_cameras_left(4);
  run_draws(STORETRACK_HONESTY_SCENE, draws_from_environment(4000, 50), subsets);
  for (const Subset& s : subsets)
    EXPECT_GT(s.mark.count(), 0) << s.name << ": no mark triangulated from the pair";
#else
  run_and_expect(two_cameras_left(4), 4000);
#endif
}

}  // namespace
}  // namespace storetrack
