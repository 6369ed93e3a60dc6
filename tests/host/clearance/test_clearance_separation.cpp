// The clearance the host states for the simulated separation against the simulator's truth
// (docs/clearance.md, "In the host"): a box store (tilted, so one corner is nearest) against a
// plane wing lower surface; the same meshes evaluated at the processor's T_p_s with its
// covariance and at the simulator's true T_p_s. Over independent seeds (each its own calibration,
// survey and noise draw; one exposure each, so the samples are independent), the k = 2 lower
// bound holds truth at 1 - Phi(-2) = 97.72 % and the two-sided |d - d_true| <= 2 u at 95.45 %,
// both inside their Binomial(seeds, p) bands (0.001 per side). The alarm bit and its counters
// against the closed-form distance of a corner to the plane.
#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

#include "sim_exposure.hpp"
#include "storetrack/clearance/sample_clearance.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/sim/scenario.hpp"
#include "storetrack/testing/counting_allocator.hpp"
#include "storetrack/uncertainty/statistics.hpp"
#include "synthetic_meshes.hpp"

namespace storetrack::clearance {
namespace {

using geometry::Mat6;
using geometry::Transform;
using geometry::Vec3;

constexpr int kExposure = 120;   // 0.3 s into the separation
constexpr double kGap_m = 0.30;  // wing plane above the store origin (pylon -z)
const Vec3 kBoxHalf(0.20, 0.06, 0.06);

// The store box in frame s, tilted 20 deg about x and y so that one corner is nearest the plane.
Body store_box() {
  Body b{"store", BodyFrame::kStore, test::box(Vec3::Zero(), kBoxHalf)};
  const Transform tilt = geometry::make_transform(Vec3(20.0, 20.0, 0) * (M_PI / 180), Vec3::Zero());
  transform_mesh(b.mesh, 1.0, tilt);
  return b;
}

// A horizontal plane in frame p, kGap_m above the store's true position at `T_p_s`.
Body wing_above(const Transform& T_p_s) {
  const Vec3 t = T_p_s.translation();
  return {"wing_lower", BodyFrame::kPylon, test::plane_patch(t.x(), t.y(), t.z() - kGap_m, 2.0, 4)};
}

TEST(ClearanceSeparation, LowerBoundAndBandCoverTruthAtTheirBinomialRates) {
#ifdef STORETRACK_SANITIZE
  const int seeds = 60;
#else
  const int seeds = 300;  // the full form: set seeds = 2000 (about 7x the time)
#endif
  const sim::Scenario sc = sim::load_scenario(test::scenario_path("store_separation"));
  int valid = 0, bound_holds = 0, band_holds = 0;
  for (int seed = 0; seed < seeds; ++seed) {
    const sim::Simulator sim(sc, 500 + static_cast<std::uint64_t>(seed));
    pipeline::ExposureProcessor proc(sim.calibrated_rig(), sim.pylon_survey(), sim.store_survey(),
                                     pipeline::ProcessorConfig{});
    const auto in = test::make_exposure(sim, kExposure);
    const pipeline::ExposureResult r = proc.process(in.exposure, in.ids);
    if (!r.T_p_s.valid) continue;
    const Transform T_true = sim.T_p_s_at(r.reference_mid_tai_ns);
    ClearanceModel model({store_box(), wing_above(sim.T_p_s_at(in.exposure.exposure_mid_tai_ns))});
    const double d_true = model.evaluate(T_true, Mat6::Zero())[0].distance_m;
    SampleClearance clearance(std::move(model), -1.0);
    msg::FtiSample s = r.sample;
    clearance.apply(r.T_p_s.T, r.T_p_s.cov, s);
    ASSERT_GT(s.u_clearance_m, 0.0f);
    ASSERT_EQ(s.clearance_part, 0);
    ++valid;
    bound_holds += d_true >= s.clearance_lower_bound_m ? 1 : 0;
    band_holds += std::abs(s.clearance_m - d_true) <= 2 * s.u_clearance_m ? 1 : 0;
    if (seed == 0)
      std::printf("seed 0: d %.5f m, u %.5f m, lower bound %.5f m, truth %.5f m\n", s.clearance_m,
                  s.u_clearance_m, s.clearance_lower_bound_m, d_true);
  }
  ASSERT_GE(valid, seeds * 9 / 10) << "the store pose was not solved at exposure " << kExposure;
  const auto bound_band = uncertainty::binomial_interval(valid, 1 - kLowerBoundMiss, 1e-3);
  const auto two_sided = uncertainty::binomial_interval(valid, 0.9545, 1e-3);
  std::printf(
      "%d seeds: truth >= lower bound %d (band [%lld, %lld]), |d - truth| <= 2u %d "
      "(band [%lld, %lld])\n",
      valid, bound_holds, static_cast<long long>(bound_band.low),
      static_cast<long long>(bound_band.high), band_holds, static_cast<long long>(two_sided.low),
      static_cast<long long>(two_sided.high));
  EXPECT_GE(bound_holds, bound_band.low);
  EXPECT_LE(bound_holds, bound_band.high);
  EXPECT_GE(band_holds, two_sided.low);
  EXPECT_LE(band_holds, two_sided.high);
}

// The store box, untilted, lowered towards a plane at z = 0 (frame p, the box below it along
// +z): its top face is at z - 0.06, so the closed-form clearance is z - 0.06; zero covariance
// makes the lower bound that distance. The alarm (threshold 0.10 m) starts when it falls below
// and ends when it rises again: one episode, one sample count per alarm sample.
TEST(ClearanceSeparation, AlarmBitAndCountersFollowTheClosedFormDistance) {
  ClearanceModel model({Body{"store", BodyFrame::kStore, test::box(Vec3::Zero(), kBoxHalf)},
                        Body{"wing_lower", BodyFrame::kPylon, test::plane_patch(0, 0, 0, 2.0, 4)}});
  SampleClearance clearance(std::move(model), 0.10);
  const double heights[] = {0.40, 0.30, 0.17, 0.15, 0.12, 0.18, 0.25};
  int expected_alarms = 0;
  for (double z : heights) {
    msg::FtiSample s{};
    clearance.apply(geometry::make_transform(Vec3::Zero(), Vec3(0, 0, z)), Mat6::Zero(), s);
    const double closed_form = z - kBoxHalf.z();
    EXPECT_NEAR(s.clearance_m, closed_form, 1e-6) << z;
    EXPECT_NEAR(s.clearance_lower_bound_m, closed_form, 1e-6) << z;
    const bool alarm = closed_form < 0.10;
    expected_alarms += alarm ? 1 : 0;
    EXPECT_EQ((s.status & msg::fti_status::kClearanceAlarm) != 0, alarm) << z;
  }
  EXPECT_EQ(clearance.counters().samples_evaluated, 7u);
  EXPECT_EQ(clearance.counters().alarm_samples, static_cast<std::uint64_t>(expected_alarms));
  EXPECT_EQ(clearance.counters().alarm_episodes, 1u);
  EXPECT_FALSE(clearance.alarm());
}

// The host calls apply() on its real-time thread: once warm (the parts' vector and the
// feature-switch scratch sized), a sample allocates nothing.
TEST(ClearanceSeparation, ApplyAllocatesNothingOnceWarm) {
  ClearanceModel model(
      {store_box(), Body{"wing_lower", BodyFrame::kPylon, test::plane_patch(0, 0, 0, 2.0, 4)}});
  SampleClearance clearance(std::move(model), 0.10);
  const Mat6 cov = Mat6::Identity() * 1e-6;
  msg::FtiSample s{};
  const auto run = [&] {
    for (int i = 0; i < 20; ++i)
      clearance.apply(geometry::make_transform(Vec3(0.01 * i, 0, 0), Vec3(0, 0, 0.3 - 0.01 * i)),
                      cov, s);
  };
  run();  // warm: the same poses size the scratch
  const long before = storetrack::testing::allocation_count();
  run();
  EXPECT_EQ(storetrack::testing::allocation_count() - before, 0);
}

TEST(ClearanceSeparation, ThresholdThatIsNotANumberRefused) {
  ClearanceModel model({Body{"store", BodyFrame::kStore, test::box(Vec3::Zero(), kBoxHalf)},
                        Body{"wing_lower", BodyFrame::kPylon, test::plane_patch(0, 0, 0, 2.0, 4)}});
  EXPECT_THROW(SampleClearance(std::move(model), std::nan("")), std::invalid_argument);
}

}  // namespace
}  // namespace storetrack::clearance
