// Body trajectories of the simulator, as functions of time t [s] since the first trigger.
#pragma once

#include <vector>

#include "storetrack/geometry/transform.hpp"
#include "storetrack/sim/scenario.hpp"

namespace storetrack::sim {

/// Store separation: T_p_s(t) (see SeparationMotion).
class SeparationTrajectory {
 public:
  explicit SeparationTrajectory(const SeparationMotion& motion) : m_(motion) {}
  geometry::Transform T_p_s(double t) const;
  /// Translation of the store origin relative to T_p_s0, pylon frame [m].
  geometry::Vec3 displacement_p(double t) const;
  /// Yaw, pitch, roll increments relative to the carriage attitude [rad].
  geometry::Vec3 ypr_increment(double t) const;

 private:
  SeparationMotion m_;
};

/// Pendulum angle from the ODE  m l2^2 theta'' + beta theta' + m g l1 sin(theta) = 0,
/// integrated with classical RK4 on a fixed 1e-4 s grid and evaluated between grid points by
/// one partial RK4 step (local error O(h^5)).
class PendulumTrajectory {
 public:
  PendulumTrajectory(const PendulumMotion& motion, double duration_s);
  double theta(double t) const;
  double theta_dot(double t) const;
  /// Mechanical energy 1/2 m l2^2 theta'^2 + m g l1 (1 - cos theta) [J].
  double energy(double t) const;
  /// Pivot frame in the pylon frame: z along the axis, x down-ish (theta = 0 direction).
  geometry::Transform T_p_pivot() const { return T_p_pivot_; }
  /// Board frame b in the pylon frame: pivot rotated by theta about its z axis.
  geometry::Transform T_p_b(double t) const;
  const PendulumMotion& motion() const { return m_; }

 private:
  void state(double t, double& theta, double& theta_dot) const;
  /// The model's coefficients per unit inertia (storetrack/pendulum/pendulum_ode.hpp).
  double omega0_sq() const { return m_.g_m_s2 * m_.l1_m / (m_.l2_m * m_.l2_m); }
  double gamma() const { return m_.damping_n_m_s / (m_.mass_kg * m_.l2_m * m_.l2_m); }
  PendulumMotion m_;
  double step_s_ = 1e-4;
  std::vector<double> theta_, theta_dot_;
  geometry::Transform T_p_pivot_ = geometry::Transform::Identity();
};

}  // namespace storetrack::sim
