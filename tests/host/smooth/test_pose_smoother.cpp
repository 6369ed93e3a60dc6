// Fixed-interval smoother of T_p_s (issue 26, host/smooth): closed forms on its own model (an
// exact constant-acceleration, constant-rate trajectory; a bias shared by every exposure), and
// the Monte Carlo acceptance against the simulator's truth: over independent simulator seeds
// (each its own calibration, survey and noise draw), the smoothed position, attitude, velocity
// and angular rate, with their total covariance (noise part + shared part), must contain the
// truth at k = 2 as often as they claim, per axis, and their mean NEES must lie in its
// chi-square band, two-sided. A smoother that treats the shared part as noise must fail.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include <gtest/gtest.h>

#include "honesty_bounds.hpp"
#include "sim_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/smooth/pose_smoother.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::smooth {
namespace {

using geometry::Mat3;
using geometry::Transform;
using geometry::Vec3;
using Acc = uncertainty::ConsistencyAccumulator<3>;

#ifdef STORETRACK_SANITIZE
constexpr int kDraws = 5;  // a smoke run under ASan/UBSan (~10x slower)
#else
constexpr int kDraws = 100;  // ~50 s in Release; the band follows the count
#endif
// The first 0.3 s of the test point at 400 fps: captive (20 ms), the ejector stroke (50 ms) and
// 230 ms of free flight.
constexpr int kExposures = 120;

int draws_from_env() {
  const char* v = std::getenv("STORETRACK_SMOOTHER_DRAWS");
  return v ? std::max(10, std::atoi(v)) : kDraws;
}

// Measurements on an exact trajectory (constant acceleration, constant angular rate in the
// pylon frame) with a stated noise covariance but no error: the smoother must reproduce the
// trajectory and its rates (its model contains it exactly).
TEST(PoseSmoother, ReproducesATrajectoryOfItsOwnModel) {
  const Vec3 p0(0.1, -0.2, 0.5), v0(1.0, -0.5, 4.0), a(-3.0, 0.4, 9.8);
  const Vec3 omega(0.05, 0.6, -0.1);
  const Mat3 R0 = geometry::rotation_from_ypr(0.1, -0.05, 0.02);
  std::vector<PoseMeasurement> ms(60);
  for (std::size_t k = 0; k < ms.size(); ++k) {
    const double t = 0.0025 * static_cast<double>(k);
    ms[k].t_ns = static_cast<time::TaiNs>(2500000) * static_cast<time::TaiNs>(k);
    ms[k].solved = true;
    ms[k].T_p_s.linear() = geometry::rotation_from_rotvec(omega * t) * R0;
    ms[k].T_p_s.translation() = p0 + v0 * t + 0.5 * a * t * t;
    // 1 um, 1 urad: the prior's pull (rates 0 at weight noise / prior, ~1e-9) is below the
    // tolerances.
    ms[k].cov_noise = geometry::Mat6::Identity() * 1e-12;
    ms[k].shared = SharedLoadings6::Zero(6, 2);
  }
  SmootherCounters counters;
  const auto out = smooth_trajectory(ms, SmootherConfig{}, &counters);
  ASSERT_EQ(out.size(), ms.size());
  EXPECT_EQ(counters.segments, 1u);
  for (std::size_t k = 0; k < out.size(); ++k) {
    const Transform& T = ms[k].T_p_s;
    EXPECT_LT((out[k].T_p_s.translation() - T.translation()).norm(), 1e-8) << k;
    EXPECT_LT(geometry::rotvec_from_rotation(out[k].T_p_s.linear() * T.linear().transpose()).norm(),
              1e-8)
        << k;
    EXPECT_LT((out[k].angular_rate_p - omega).norm(), 1e-5) << k;
    const double t = 0.0025 * static_cast<double>(k);
    EXPECT_LT((out[k].velocity_p - (v0 + a * t)).norm(), 1e-5) << k;
    EXPECT_LT((out[k].accel_p - a).norm(), 1e-2) << k;
    EXPECT_LT(out[k].angular_accel_p.norm(), 1e-2) << k;
  }
}

// A bias loaded identically on every exposure (a constant error of the pose in the pylon frame)
// passes through the smoother whole: the smoothed pose carries exactly that covariance and the
// rates none (the smoother's gains on the pose sum to identity, on the rates to zero), however
// many exposures are averaged. A gap splits the segments.
TEST(PoseSmoother, ConstantSharedBiasIsNotAveragedAndHasNoRate) {
  SharedLoadings6 M(6, 3);
  M.setRandom();
  M *= 1e-3;
  std::vector<PoseMeasurement> ms(80);
  for (std::size_t k = 0; k < ms.size(); ++k) {
    ms[k].t_ns = static_cast<time::TaiNs>(2500000) * static_cast<time::TaiNs>(k);
    if (k >= 40) ms[k].t_ns += 30000000;  // a 32.5 ms gap: a second segment
    ms[k].solved = k != 10;               // one unsolved exposure inside the first
    ms[k].T_p_s.translation() = Vec3(0, 0, 0.01 * static_cast<double>(k));
    ms[k].cov_noise = geometry::Mat6::Identity() * 1e-8;
    ms[k].shared = M;
  }
  SmootherCounters counters;
  const auto out = smooth_trajectory(ms, SmootherConfig{}, &counters);
  ASSERT_EQ(out.size(), ms.size());
  EXPECT_EQ(counters.segments, 2u);
  EXPECT_EQ(counters.predicted, 1u);
  const geometry::Mat6 expected = M * M.transpose();
  for (const SmoothedState& s : out) {
    const geometry::Mat6 pose_part = s.cov_shared().topLeftCorner<6, 6>();
    const Eigen::Matrix<double, 12, 12> rates_part = s.cov_shared().bottomRightCorner<12, 12>();
    EXPECT_LT((pose_part - expected).norm(), 1e-9 * expected.norm());
    EXPECT_LT(rates_part.norm(), 1e-9 * expected.norm());
    // The noise part is averaged: below the per-exposure noise.
    if (s.measured) {
      EXPECT_LT(s.cov_noise(kPosition, kPosition), 1e-8);
    }
  }
}

// ---- Monte Carlo acceptance against the simulator's truth ----------------------------------

struct Scores {
  Acc position, attitude, velocity, rate;
  // Per axis: sums of the smoothed and per-exposure noise standard deviations (measured
  // exposures), for the noise reduction.
  std::array<double, 6> sum_sigma_smoothed{}, sum_sigma_exposure{};
  std::int64_t measured = 0;
  std::array<double, 6> sum_u_rates{};  ///< mean total u of velocity (0-2), rate (3-5)
};

// The smoother configurations scored on the same processed exposures.
// - "simulated world": the process noise of the simulator's store, whose aerodynamic
//   acceleration is a constant (SeparationMotion: zero jerk after the stroke; its attitude's
//   jerk is the Euler-angle kinematics', kept at the product's angular envelope) and whose
//   ejector steps are the product's. Asserted two-sided.
// - "product defaults": the aerodynamic jerk of a real store (SmootherConfig), which the
//   simulator does not have: states more than the simulated world realises. Printed, and
//   asserted not to under-state (coverage at least the band's lower end).
// - "WRONG": the shared part fed as independent noise. Must be rejected.
enum Variant { kWorld = 0, kProduct = 1, kWrong = 2, kVariants = 3 };
constexpr const char* kVariantNames[kVariants] = {
    "smoother, simulated world's process noise (asserted)",
    "smoother, product defaults (aerodynamic jerk; printed)",
    "WRONG: shared part treated as noise (must fail)"};

SmootherConfig variant_config(int v) {
  SmootherConfig c;
  if (v != kProduct) c.aero_accel_sigma_m_s2 = 0;
  return c;
}

struct Window {
  explicit Window(const char* n) : name(n) {}
  const char* name;
  std::array<Scores, kVariants> scores;
};

struct Truth {
  Transform T;
  Vec3 velocity, rate;
};

// The simulator's truth at t: pose, and velocity and angular rate (left, pylon frame) by a
// central difference over +-10 us (error ~ jerk h^2 / 6, below 1e-6 m/s; at the ejector's
// acceleration steps below a h / 2 = 4e-4 m/s, far below any stated u).
Truth truth_at(const sim::Simulator& sim, time::TaiNs t) {
  constexpr time::TaiNs h = 10000;
  const Transform a = sim.T_p_s_at(t - h), b = sim.T_p_s_at(t + h);
  Truth out;
  out.T = sim.T_p_s_at(t);
  out.velocity = (b.translation() - a.translation()) / 2e-5;
  out.rate = geometry::rotvec_from_rotation(b.linear() * a.linear().transpose()) / 2e-5;
  return out;
}

void score(const SmoothedState& s, const Truth& truth, Scores& sc) {
  const StateMatrix C = s.cov();
  sc.position.add(truth.T.translation() - s.T_p_s.translation(),
                  C.block<3, 3>(kPosition, kPosition));
  sc.attitude.add(geometry::rotvec_from_rotation(truth.T.linear() * s.T_p_s.linear().transpose()),
                  C.block<3, 3>(kAttitude, kAttitude));
  sc.velocity.add(truth.velocity - s.velocity_p, C.block<3, 3>(kVelocity, kVelocity));
  sc.rate.add(truth.rate - s.angular_rate_p, C.block<3, 3>(kAngularRate, kAngularRate));
  for (int a = 0; a < 3; ++a) {
    sc.sum_u_rates[static_cast<std::size_t>(a)] += std::sqrt(C(kVelocity + a, kVelocity + a));
    sc.sum_u_rates[static_cast<std::size_t>(3 + a)] +=
        std::sqrt(C(kAngularRate + a, kAngularRate + a));
  }
  if (!s.measured) return;
  ++sc.measured;
  for (int i = 0; i < 6; ++i) {
    sc.sum_sigma_smoothed[static_cast<std::size_t>(i)] += std::sqrt(s.cov_noise(i, i));
    sc.sum_sigma_exposure[static_cast<std::size_t>(i)] += std::sqrt(s.cov_noise_per_exposure(i, i));
  }
}

// The deliberately wrong smoother: the whole per-exposure covariance as independent noise (the
// shared calibration and survey errors "averaged away").
PoseMeasurement shared_as_noise(const pipeline::ExposureResult& r) {
  PoseMeasurement m = measurement_from(r);
  if (m.solved) {
    m.cov_noise = r.T_p_s.cov;
    m.shared.setZero();
  }
  return m;
}

// Windows of time since the first exposure: captive, the release transient (release - 5 ms to
// the end of the stroke + 25 ms), free flight.
int window_of(const sim::Scenario& sc, time::TaiNs t) {
  const double s = static_cast<double>(t - sc.start_tai_ns) * 1e-9;
  const double release = sc.separation.release_time_s;
  if (s < release - 0.005) return 0;
  if (s < release + sc.separation.ejector_duration_s + 0.025) return 1;
  return 2;
}

void run_draw(const sim::Scenario& scenario, std::uint64_t seed, std::vector<Window>& windows,
              std::array<int, 3>& present, std::uint64_t& steps) {
  const sim::Simulator sim(scenario, seed);
  pipeline::ExposureProcessor proc(sim.calibrated_rig(), sim.pylon_survey(), sim.store_survey(),
                                   pipeline::ProcessorConfig{});
  std::vector<PoseMeasurement> honest, wrong;
  for (int k = 0; k < std::min(kExposures, sim.num_exposures()); ++k) {
    const test::SimExposure in = test::make_exposure(sim, k);
    const pipeline::ExposureResult r = proc.process(in.exposure, in.ids);
    honest.push_back(measurement_from(r));
    wrong.push_back(shared_as_noise(r));
  }
  std::array<std::vector<SmoothedState>, kVariants> out;
  for (int v = 0; v < kVariants; ++v) {
    SmootherCounters counters;
    out[static_cast<std::size_t>(v)] =
        smooth_trajectory(v == kWrong ? wrong : honest, variant_config(v), &counters);
    if (v == kWorld) steps += counters.steps;
  }
  ASSERT_EQ(out[kWorld].size(), out[kWrong].size());
  ASSERT_EQ(out[kWorld].size(), out[kProduct].size());
  std::array<bool, 3> seen{};
  for (std::size_t i = 0; i < out[kWorld].size(); ++i) {
    const Truth truth = truth_at(sim, out[kWorld][i].t_ns);
    const auto w = static_cast<std::size_t>(window_of(scenario, out[kWorld][i].t_ns));
    seen[w] = true;
    for (std::size_t v = 0; v < kVariants; ++v) {
      score(out[v][i], truth, windows[w].scores[v]);
      score(out[v][i], truth, windows[3].scores[v]);
    }
  }
  for (int w = 0; w < 3; ++w)
    present[static_cast<std::size_t>(w)] += seen[static_cast<std::size_t>(w)] ? 1 : 0;
}

void print_acc(const char* what, const Acc& acc) {
  std::printf("    %-10s n=%6lld coverage(k=2) %.4f %.4f %.4f  mean NEES %.3f\n", what,
              static_cast<long long>(acc.count()), acc.coverage(0), acc.coverage(1),
              acc.coverage(2), acc.mean_nees());
}

bool inside(const Acc& acc, const test::HonestyBounds& b) {
  bool in = acc.mean_nees() >= b.nees_low && acc.mean_nees() <= b.nees_high;
  for (int a = 0; a < 3; ++a)
    in = in && acc.coverage(a) >= b.coverage_low && acc.coverage(a) <= b.coverage_high;
  return in;
}

void print_reduction(const Scores& h) {
  const double n = static_cast<double>(std::max<std::int64_t>(h.measured, 1));
  std::printf(
      "    noise part, smoothed / per exposure (mean sigma): rx %.3f ry %.3f rz %.3f "
      "x %.3f y %.3f z %.3f\n",
      h.sum_sigma_smoothed[0] / h.sum_sigma_exposure[0],
      h.sum_sigma_smoothed[1] / h.sum_sigma_exposure[1],
      h.sum_sigma_smoothed[2] / h.sum_sigma_exposure[2],
      h.sum_sigma_smoothed[3] / h.sum_sigma_exposure[3],
      h.sum_sigma_smoothed[4] / h.sum_sigma_exposure[4],
      h.sum_sigma_smoothed[5] / h.sum_sigma_exposure[5]);
  std::printf("    per exposure noise sigma: r %.4f %.4f %.4f mrad, p %.4f %.4f %.4f mm\n",
              h.sum_sigma_exposure[0] / n * 1e3, h.sum_sigma_exposure[1] / n * 1e3,
              h.sum_sigma_exposure[2] / n * 1e3, h.sum_sigma_exposure[3] / n * 1e3,
              h.sum_sigma_exposure[4] / n * 1e3, h.sum_sigma_exposure[5] / n * 1e3);
  const double m = static_cast<double>(std::max<std::int64_t>(h.velocity.count(), 1));
  std::printf("    mean total u: velocity %.2f %.2f %.2f mm/s, rate %.2f %.2f %.2f mrad/s\n",
              h.sum_u_rates[0] / m * 1e3, h.sum_u_rates[1] / m * 1e3, h.sum_u_rates[2] / m * 1e3,
              h.sum_u_rates[3] / m * 1e3, h.sum_u_rates[4] / m * 1e3, h.sum_u_rates[5] / m * 1e3);
}

void print_window(const Window& w, int n_eff) {
  const test::HonestyBounds band = test::derived_bounds(n_eff, 3);
  std::printf("  %s (n_eff = %d draws): coverage [%.4f, %.4f], mean NEES [%.3f, %.3f]\n", w.name,
              n_eff, band.coverage_low, band.coverage_high, band.nees_low, band.nees_high);
  for (std::size_t v = 0; v < kVariants; ++v) {
    const Scores& sc = w.scores[v];
    std::printf("   %s\n", kVariantNames[v]);
    print_acc("position", sc.position);
    print_acc("attitude", sc.attitude);
    print_acc("velocity", sc.velocity);
    print_acc("rate", sc.rate);
  }
  for (const std::size_t v : {std::size_t{kWorld}, std::size_t{kProduct}}) {
    std::printf("   %s:\n", v == kWorld ? "simulated world" : "product defaults");
    print_reduction(w.scores[v]);
  }
}

// Acceptance, derived: the samples of one draw share its calibration and survey draw (and the
// smoother correlates neighbouring samples), so the effective sample size lies between the
// number of draws (full correlation) and the number of samples; the band of n_eff = draws is
// the widest the correlation allows (binomial 95.45 %, alpha 0.001 per side; mean NEES of
// d = 3: chi-square(3 n_eff) / n_eff). Scored per window: the release transient on its own.
TEST(PoseSmoother, SmoothedTrajectoryIsHonestAgainstTheSimulatorsTruth) {
  const int draws = draws_from_env();
  const sim::Scenario scenario = sim::load_scenario(test::scenario_path("store_separation"));
  std::vector<Window> windows;
  for (const char* name : {"captive", "release transient", "free flight", "whole trajectory"})
    windows.emplace_back(name);
  std::array<int, 3> present{};
  std::uint64_t steps = 0;
  for (int d = 0; d < draws; ++d)
    run_draw(scenario, 260000 + static_cast<std::uint64_t>(d), windows, present, steps);
  std::printf(
      "%d draws (seeds 260000..%d); intervals modelled with an acceleration step: %.2f "
      "per draw\n",
      draws, 260000 + draws - 1, static_cast<double>(steps) / draws);
  for (std::size_t w = 0; w < windows.size(); ++w) {
    const int n_eff = w < 3 ? present[w] : draws;
    print_window(windows[w], n_eff);
    const test::HonestyBounds band = test::derived_bounds(n_eff, 3);
    const Scores& h = windows[w].scores[kWorld];
    const Scores& product = windows[w].scores[kProduct];
    for (const auto& [what, acc] :
         {std::pair{"position", &product.position}, std::pair{"attitude", &product.attitude},
          std::pair{"velocity", &product.velocity}, std::pair{"angular rate", &product.rate}})
      for (int a = 0; a < 3; ++a)
        EXPECT_GE(acc->coverage(a), band.coverage_low)
            << windows[w].name << " product defaults " << what << a;
    for (const auto& [what, acc] :
         {std::pair{"position", &h.position}, std::pair{"attitude", &h.attitude},
          std::pair{"velocity", &h.velocity}, std::pair{"angular rate", &h.rate}}) {
      for (int a = 0; a < 3; ++a) {
        EXPECT_GE(acc->coverage(a), band.coverage_low) << windows[w].name << " " << what << a;
        EXPECT_LE(acc->coverage(a), band.coverage_high) << windows[w].name << " " << what << a;
      }
      EXPECT_GE(acc->mean_nees(), band.nees_low) << windows[w].name << " " << what;
      EXPECT_LE(acc->mean_nees(), band.nees_high) << windows[w].name << " " << what;
    }
  }
  // The wrong smoother must be rejected over the whole trajectory (position or attitude).
  const test::HonestyBounds band = test::derived_bounds(draws, 3);
  const Scores& wrong = windows[3].scores[kWrong];
  EXPECT_FALSE(inside(wrong.position, band) && inside(wrong.attitude, band))
      << "the shared part treated as noise passes: the test cannot see it";
}

}  // namespace
}  // namespace storetrack::smooth
