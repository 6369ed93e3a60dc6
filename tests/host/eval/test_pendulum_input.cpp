// storetrack-eval pendulum: the model's ODE against closed forms, and bad input refused with a
// message naming the file and the field or the reason (issue 10).
#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "pendulum_recordings.hpp"
#include "storetrack/eval/pendulum.hpp"

namespace storetrack {
namespace {

TEST(PendulumModel, SmallAmplitudeMatchesDampedOscillator) {
  // Linearised: theta = theta0 e^(-g t/2) (cos wd t + g/(2 wd) sin wd t); the nonlinearity adds
  // O(theta0^3) ~ 1e-18 rad at theta0 = 1e-6.
  const double w0_sq = 12.5, gamma = 0.3, theta0 = 1e-6;
  const double wd = std::sqrt(w0_sq - gamma * gamma / 4);
  std::vector<double> t, theta, rate;
  for (int i = -3; i < 400; ++i)
    t.push_back(i * 0.00731);
  eval::pendulum_angles(w0_sq, gamma, theta0, t, theta, rate);
  for (size_t i = 0; i < t.size(); ++i) {
    const double tau = std::max(0.0, t[i]);
    const double expected = theta0 * std::exp(-gamma * tau / 2) *
                            (std::cos(wd * tau) + gamma / (2 * wd) * std::sin(wd * tau));
    ASSERT_NEAR(theta[i], expected, 1e-12 * theta0 + 1e-15) << "t = " << t[i];
  }
}

TEST(PendulumModel, LargeAmplitudePeriodIsTheEllipticIntegral) {
  // Undamped from rest at theta0: period 4 K(sin(theta0/2)) / omega0 (K: complete elliptic
  // integral of the first kind, std::comp_ellint_1); -theta0 at half a period.
  const double w0_sq = 12.49, theta0 = 2.9;
  const double period = 4 * std::comp_ellint_1(std::sin(theta0 / 2)) / std::sqrt(w0_sq);
  std::vector<double> theta, rate;
  eval::pendulum_angles(w0_sq, 0, theta0, {period / 2, period, 3 * period}, theta, rate);
  EXPECT_NEAR(theta[0], -theta0, 1e-8);
  EXPECT_NEAR(theta[1], theta0, 1e-8);
  EXPECT_NEAR(theta[2], theta0, 3e-8);
  EXPECT_NEAR(rate[1], 0, 1e-7);
}

/// The rows of `csv` whose trigger_seq is at least `first_seq` (header kept).
std::string from_seq(const std::string& csv, long first_seq) {
  std::istringstream in(csv);
  std::string line, out;
  std::getline(in, line);
  out = line + "\n";
  while (std::getline(in, line))
    if (std::stol(line.substr(0, line.find(','))) >= first_seq) out += line + "\n";
  return out;
}

std::string refusal(const std::vector<std::pair<std::string, std::string>>& files) {
  try {
    std::vector<eval::MarksRecording> recordings;
    for (const auto& [name, text] : files)
      recordings.push_back(eval::parse_marks_csv(text, name));
    eval::PendulumOptions options;
    eval::identify_pendulum(eval::pendulum_runs(recordings, options), options);
  } catch (const eval::EvalInputError& e) {
    return e.what();
  }
  return "accepted";
}

TEST(PendulumInput, RunsTooShortAreRefusedNamingTheFileAndWhy) {
  const sim::Scenario sc = test::pendulum_scenario(false);
  // 15 exposures (37 ms, released after 10 ms): the board has turned by ~0.03 deg, below the
  // 0.17 deg motion threshold: no release is seen.
  const std::string held = test::simulated_pendulum_csv(sc, 3, true, 15);
  EXPECT_EQ(refusal({{"held.csv", held}})
                .rfind("held.csv: run too short to identify the "
                       "pendulum: no release seen",
                       0),
            0u)
      << refusal({{"held.csv", held}});
  // 60 exposures: it moves, but too few exposures follow the release.
  const std::string brief = test::simulated_pendulum_csv(sc, 3, true, 60);
  EXPECT_NE(refusal({{"brief.csv", brief}}).find("brief.csv: run too short"), std::string::npos);
  EXPECT_NE(refusal({{"brief.csv", brief}}).find("exposures after the release"), std::string::npos)
      << refusal({{"brief.csv", brief}});
  // A recording that starts mid-swing has no held exposure: theta0 and t0 are not separable.
  const std::string late =
      from_seq(test::simulated_pendulum_csv(sc, 3, true, 480, 4), sc.first_trigger_seq + 300);
  EXPECT_NE(refusal({{"late.csv", late}})
                .find("late.csv: run too short to identify the "
                      "pendulum: the recording starts after the release"),
            std::string::npos)
      << refusal({{"late.csv", late}});
  // One good run does not rescue a short one: the short one is named.
  const std::string good = test::simulated_pendulum_csv(sc, 4, true, 480, 4);
  EXPECT_EQ(refusal({{"good.csv", good}}), "accepted");
  EXPECT_NE(refusal({{"good.csv", good}, {"held.csv", held}}).find("held.csv: run too short"),
            std::string::npos);
}

TEST(PendulumInput, MissingColumnsAreRefusedNamingTheField) {
  const std::string header =
      "trigger_seq [1],mark_id [1],body [p|s|?],excluded [0|1],x_w [m],"
      "y_w [m],z_w [m],u_x_w [m],u_y_w [m],u_z_w [m]\n";
  const std::string no_time = header + "1,200,s,0,1,2,3,0.001,0.001,0.001\n";
  EXPECT_EQ(refusal({{"no_time.csv", no_time}}),
            "no_time.csv:1: reference_mid_tai_ns: missing column in the header (the pendulum "
            "needs each exposure's time)");
  const std::string no_z =
      "trigger_seq [1],reference_mid_tai_ns [ns],mark_id [1],body [p|s|?],"
      "excluded [0|1],x_w [m],y_w [m],u_x_w [m],u_y_w [m],u_z_w [m]\n";
  EXPECT_EQ(refusal({{"no_z.csv", no_z}}), "no_z.csv:1: z_w: missing column in the header");
  const std::string pylon_only =
      "trigger_seq [1],reference_mid_tai_ns [ns],mark_id [1],body [p|s|?],excluded [0|1],x_w [m],"
      "y_w [m],z_w [m],u_x_w [m],u_y_w [m],u_z_w [m]\n1,5,0,p,0,1,2,3,0.001,0.001,0.001\n";
  EXPECT_EQ(refusal({{"pylon.csv", pylon_only}}),
            "pylon.csv: body: no sample of body 's' (the pendulum's marks, --body)");
  const std::string bad_time =
      "trigger_seq [1],reference_mid_tai_ns [ns],mark_id [1],body [p|s|?],excluded [0|1],x_w [m],"
      "y_w [m],z_w [m],u_x_w [m],u_y_w [m],u_z_w [m]\n1,5.5,200,s,0,1,2,3,0.001,0.001,0.001\n";
  EXPECT_EQ(refusal({{"t.csv", bad_time}}),
            "t.csv:2: reference_mid_tai_ns: expected an integer, got '5.5'");
}

}  // namespace
}  // namespace storetrack

namespace storetrack {
namespace {

// The simulator's pendulum truth (truth_pendulum.json) against its own mark positions: the
// board pose, and the model's parameters (pivot, normal, r, phi, h, theta), must reproduce every
// mark in the host's world frame at every exposure. Also: theta follows the energy balance.
TEST(PendulumTruth, ParametersAndPoseReproduceTheMarks) {
  for (bool ccw : {false, true}) {
    const sim::Scenario sc = test::pendulum_scenario(ccw);
    const sim::Simulator sim(sc, 11);
    const sim::PendulumTruth t = sim::pendulum_truth(sim);
    ASSERT_EQ(t.exposures.size(), static_cast<size_t>(sim.num_exposures()));
    const geometry::Vec3 down(0, 0, 1);  // world z points down (docs/conventions.md)
    const geometry::Vec3 e1 = (down - down.dot(t.normal_w) * t.normal_w).normalized();
    const geometry::Vec3 e2 = t.normal_w.cross(e1);
    for (size_t k = 0; k < t.exposures.size(); k += 37) {
      const sim::PendulumExposureTruth& e = t.exposures[k];
      for (const sim::PendulumMarkTruth& m : t.marks) {
        const geometry::Vec3 p = test::true_mark_in_host_world(sim, m.id, e.reference_tai_ns);
        const geometry::Vec3 model = t.pivot_w +
                                     m.radius_m * (std::cos(e.theta_rad + m.angle_rad) * e1 +
                                                   std::sin(e.theta_rad + m.angle_rad) * e2) +
                                     m.offset_m * t.normal_w;
        EXPECT_LT((model - p).norm(), 1e-9) << "exposure " << k << " mark " << m.id;
        const survey::SurveyedMark* body = nullptr;
        for (const survey::SurveyedMark& s : sc.pendulum.marks)
          if (s.id == m.id) body = &s;
        ASSERT_NE(body, nullptr);
        EXPECT_LT((e.T_w0_b * body->p_body - p).norm(), 1e-9) << "exposure " << k;
      }
    }
    // Held at theta0 before the release, then energy lost only to damping (beta > 0): the
    // energy never rises and stays within 1 % of its start over 1.2 s.
    const sim::PendulumMotion& m = t.motion;
    const auto energy = [&](const sim::PendulumExposureTruth& e) {
      return 0.5 * m.l2_m * m.l2_m * e.theta_dot_rad_s * e.theta_dot_rad_s +
             m.g_m_s2 * m.l1_m * (1 - std::cos(e.theta_rad));
    };
    EXPECT_DOUBLE_EQ(t.exposures.front().theta_rad, m.theta0_rad);
    for (size_t k = 1; k < t.exposures.size(); ++k) {
      EXPECT_LE(energy(t.exposures[k]), energy(t.exposures[k - 1]) + 1e-12);
      EXPECT_GT(energy(t.exposures[k]), 0.99 * energy(t.exposures[0]));
    }
  }
}

}  // namespace
}  // namespace storetrack
