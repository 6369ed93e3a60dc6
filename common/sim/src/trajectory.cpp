#include "storetrack/sim/trajectory.hpp"

#include <algorithm>
#include <cmath>

#include "storetrack/pendulum/pendulum_ode.hpp"

namespace storetrack::sim {

geometry::Vec3 SeparationTrajectory::displacement_p(double t) const {
  const double tau = t - m_.release_time_s;
  if (tau <= 0) return geometry::Vec3::Zero();
  const double te = m_.ejector_duration_s;
  const double a_eject = 2 * m_.ejector_stroke_m / (te * te);
  if (tau <= te) return {0, 0, 0.5 * a_eject * tau * tau};
  const double v_end = a_eject * te;
  const double s = tau - te;
  return geometry::Vec3(0, 0, m_.ejector_stroke_m + v_end * s) + 0.5 * m_.accel_p_m_s2 * s * s;
}

geometry::Vec3 SeparationTrajectory::ypr_increment(double t) const {
  const double tau = t - m_.release_time_s;
  if (tau <= 0) return geometry::Vec3::Zero();
  const double te = m_.ejector_duration_s;
  // Rates ramp linearly during the stroke (ejector moment), then grow with constant accel.
  if (tau <= te) return m_.rate_ypr_rad_s * (tau * tau / (2 * te));
  const double s = tau - te;
  return m_.rate_ypr_rad_s * (te / 2 + s) + 0.5 * m_.accel_ypr_rad_s2 * s * s;
}

geometry::Transform SeparationTrajectory::T_p_s(double t) const {
  const geometry::Vec3 ypr = ypr_increment(t);
  geometry::Transform T = m_.T_p_s0;
  // Attitude increments are about the store's own axes (body rates).
  T.linear() = m_.T_p_s0.linear() * geometry::rotation_from_ypr(ypr[0], ypr[1], ypr[2]);
  T.translation() = m_.T_p_s0.translation() + displacement_p(t);
  return T;
}

PendulumTrajectory::PendulumTrajectory(const PendulumMotion& motion, double duration_s)
    : m_(motion) {
  // Pivot frame: z = axis, x = the downward direction (z_p) projected normal to the axis.
  const geometry::Vec3 z = m_.axis_p.normalized();
  geometry::Vec3 down(0, 0, 1);
  if (std::abs(down.dot(z)) > 0.95) down = geometry::Vec3(1, 0, 0);
  const geometry::Vec3 x = (down - down.dot(z) * z).normalized();
  const geometry::Vec3 y = z.cross(x);
  T_p_pivot_.linear().col(0) = x;
  T_p_pivot_.linear().col(1) = y;
  T_p_pivot_.linear().col(2) = z;
  T_p_pivot_.translation() = m_.pivot_p_m;

  const int n = static_cast<int>(std::ceil(std::max(duration_s, 0.0) / step_s_)) + 2;
  theta_.resize(static_cast<std::size_t>(n));
  theta_dot_.resize(static_cast<std::size_t>(n));
  double th = m_.theta0_rad, om = m_.theta_dot0_rad_s;
  for (int i = 0; i < n; ++i) {
    theta_[static_cast<std::size_t>(i)] = th;
    theta_dot_[static_cast<std::size_t>(i)] = om;
    pendulum::rk4_step(omega0_sq(), gamma(), th, om, step_s_);
  }
}

void PendulumTrajectory::state(double t, double& theta, double& theta_dot) const {
  const double tau = std::max(0.0, t - m_.release_time_s);
  const double pos = tau / step_s_;
  const std::size_t last = theta_.size() - 1;
  std::size_t i = static_cast<std::size_t>(std::min(std::floor(pos), static_cast<double>(last)));
  const double h = tau - static_cast<double>(i) * step_s_;
  double th = theta_[i], om = theta_dot_[i];
  if (h > 0) pendulum::rk4_step(omega0_sq(), gamma(), th, om, h);
  theta = th;
  theta_dot = om;
}

double PendulumTrajectory::theta(double t) const {
  double a, w;
  state(t, a, w);
  return a;
}

double PendulumTrajectory::theta_dot(double t) const {
  double a, w;
  state(t, a, w);
  return w;
}

double PendulumTrajectory::energy(double t) const {
  double a, w;
  state(t, a, w);
  return 0.5 * m_.mass_kg * m_.l2_m * m_.l2_m * w * w +
         m_.mass_kg * m_.g_m_s2 * m_.l1_m * (1 - std::cos(a));
}

geometry::Transform PendulumTrajectory::T_p_b(double t) const {
  geometry::Transform R = geometry::Transform::Identity();
  R.linear() = Eigen::AngleAxisd(theta(t), geometry::Vec3::UnitZ()).toRotationMatrix();
  return T_p_pivot_ * R;
}

}  // namespace storetrack::sim
