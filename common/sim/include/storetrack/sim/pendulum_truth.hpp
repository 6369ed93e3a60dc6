// The pendulum scenario's pose truth in the host's world frame (w0, see MarkTruth::p_w0): what
// storetrack-eval pendulum identifies (docs/evaluation.md), written as truth_pendulum.json.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "storetrack/geometry/transform.hpp"
#include "storetrack/sim/simulator.hpp"

namespace storetrack::sim {

struct PendulumMarkTruth {
  int id = 0;
  double radius_m = 0;   ///< distance from the axis
  double angle_rad = 0;  ///< from the centre-of-mass line (board x), about the axis
  double offset_m = 0;   ///< along the axis from the pivot
};

struct PendulumExposureTruth {
  std::uint32_t trigger_seq = 0;
  time::TaiNs reference_tai_ns = 0;
  double theta_rad = 0, theta_dot_rad_s = 0;
  geometry::Transform T_w0_b = geometry::Transform::Identity();  ///< board pose, host world
};

struct PendulumTruth {
  PendulumMotion motion;               ///< l1, l2, m, beta, g, theta0, release (scenario)
  double equivalent_length_m = 0;      ///< l2^2 / l1
  double damping_per_inertia_1_s = 0;  ///< beta / (m l2^2)
  time::TaiNs release_tai_ns = 0;
  geometry::Vec3 pivot_w = geometry::Vec3::Zero();    ///< host world frame (w0)
  geometry::Vec3 normal_w = geometry::Vec3::UnitZ();  ///< rotation axis (theta positive about it)
  std::vector<PendulumMarkTruth> marks;
  std::vector<PendulumExposureTruth> exposures;
};

/// Throws std::invalid_argument unless the scenario is a pendulum.
PendulumTruth pendulum_truth(const Simulator& sim);
void write_pendulum_truth_json(const Simulator& sim, const std::string& path);

}  // namespace storetrack::sim
