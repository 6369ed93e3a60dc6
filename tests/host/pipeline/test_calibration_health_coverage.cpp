// Store pose coverage after a camera moved in its mount, against simulator truth over
// independent seeds (docs/calibration-health.md): flag collapses, correct and exclude hold.
// STORETRACK_HEALTH_LONG=1: 1000 seeds; the sanitizer tree runs 30.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <optional>

#include <gtest/gtest.h>

#include "calibration_health_scenes.hpp"
#include "storetrack/pipeline/calibration_health.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::pipeline {
namespace {

using geometry::Vec3;

// Store pose coverage after a shift, over independent seeds (each its own calibration error,
// survey and noise; one exposure per seed, well after the correction): `flag` keeps the old
// extrinsic and its k = 2 coverage collapses; `correct` uses the re-estimated one with its
// added covariance and stays inside the Binomial(seeds, 95.45 %) band (0.001 per side);
// `exclude` drops the camera (3 cameras left) and stays inside it too.
struct CoverageCount {
  int flagged = 0;
  std::array<int, 3> flag{}, correct{}, exclude{};
};

bool covered(const sim::Simulator& sim, const ExposureResult& r, int axis) {
  if (!r.T_p_s.valid) return false;
  const double e =
      sim.T_p_s_at(r.reference_mid_tai_ns).translation()(axis) - r.T_p_s.T.translation()(axis);
  return std::abs(e) <= 2 * std::sqrt(r.cov_xyz_ypr(axis, axis));
}

void count_coverage(std::uint64_t seed, const sim::CameraMotion& motion, CoverageCount& count) {
  CalibrationHealthConfig config;
  config.window_exposures = 5;
  config.baseline_windows = 4;  // 20 exposures; the step at 22, corrected at the end of 29
  const int n = 40;
  const sim::Simulator sim(static_scenario(n, motion), seed);
  const auto rig = sim.calibrated_rig();
  ExposureProcessor flag(rig, sim.pylon_survey(), sim.store_survey(), ProcessorConfig{});
  std::array<std::optional<ExposureProcessor>, 2> proc;
  std::array<std::optional<CalibrationHealthGuard>, 2> guard;
  const std::array<CalibrationHealthMode, 2> modes{CalibrationHealthMode::kCorrect,
                                                   CalibrationHealthMode::kExclude};
  for (int m = 0; m < 2; ++m) {
    proc[m].emplace(rig, sim.pylon_survey(), sim.store_survey(), ProcessorConfig{});
    guard[m].emplace(rig, sim.pylon_survey(), config, modes[m]);
  }
  for (int k = 0; k < n; ++k) {
    const auto in = test::make_exposure(sim, k);
    const ExposureResult rf = flag.process(in.exposure, in.ids);
    for (int m = 0; m < 2; ++m) {
      const AlignedExposure& e = guard[m]->filter(in.exposure);
      ExposureResult r = proc[m]->process(e, in.ids);
      if (guard[m]->observe(e, r))
        proc[m].emplace(guard[m]->rig(), sim.pylon_survey(), sim.store_survey(), ProcessorConfig{});
      if (k + 1 < n) continue;
      if (m == 0) count.flagged += guard[m]->flagged() ? 1 : 0;
      for (int a = 0; a < 3; ++a) {
        (m == 0 ? count.correct : count.exclude)[a] += covered(sim, r, a);
        if (m == 0) count.flag[a] += covered(sim, rf, a);
      }
    }
  }
}

void expect_coverage(const Vec3& rotation_deg, const Vec3& translation_m) {
  sim::CameraMotion motion;
  motion.enabled = true;
  motion.start_s = 21.5 / 400.0;
  motion.rotation_rad = rotation_deg * kDeg;
  motion.translation_m = translation_m;
#ifdef STORETRACK_SANITIZE
  // The sanitizer tree's form (memory and UB checks, ~10x slower): 30 seeds. Its band is derived
  // for 30, but 30 seeds cannot tell flag's collapse (~85 %) from 95.45 %: that claim is left to
  // the Release tree and said so.
  const int seeds = 30;
  const bool collapse_asserted = false;
#else
  const int seeds = long_form() ? 1000 : 150;
  const bool collapse_asserted = true;
#endif
  CoverageCount count;
  for (int s = 0; s < seeds; ++s)
    count_coverage(1000 + static_cast<std::uint64_t>(s), motion, count);
  const auto band = uncertainty::binomial_interval(seeds, 0.9545, 1e-3);
  EXPECT_EQ(count.flagged, seeds);
  for (int a = 0; a < 3; ++a) {
    std::printf(
        "axis %d k=2 coverage of %d seeds: flag %d, correct %d, exclude %d; band [%lld, "
        "%lld]\n",
        a, seeds, count.flag[a], count.correct[a], count.exclude[a],
        static_cast<long long>(band.low), static_cast<long long>(band.high));
    EXPECT_GE(count.correct[a], band.low) << a;
    EXPECT_LE(count.correct[a], band.high) << a;
    EXPECT_GE(count.exclude[a], band.low) << a;
    EXPECT_LE(count.exclude[a], band.high) << a;
  }
  // Collapsed: below the band on at least one axis.
  const int flag_lowest = std::min({count.flag[0], count.flag[1], count.flag[2]});
  if (collapse_asserted)
    EXPECT_LT(flag_lowest, band.low);
  else
    std::printf(
        "not asserted in this form (1 check left out): flag collapses below %lld (lowest axis: "
        "%d)\n",
        static_cast<long long>(band.low), flag_lowest);
}

TEST(CalibrationHealth, StoreCoverageAfterA0p1DegShiftFlagCollapsesCorrectHolds) {
  expect_coverage(Vec3(0, 0.1, 0), Vec3(0.0005, 0, 0));
}

}  // namespace
}  // namespace storetrack::pipeline
