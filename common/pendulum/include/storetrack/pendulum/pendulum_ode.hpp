// The damped pendulum of SisTrO's dynamic calibration (docs/evaluation.md, "Pendulum"):
//   m l2^2 theta'' + beta theta' + m g l1 sin(theta) = 0   (theta = 0: centre of mass below),
// divided by m l2^2: theta'' = -gamma theta' - omega0^2 sin(theta) with gamma = beta / (m l2^2)
// and omega0^2 = g l1 / l2^2. One classical RK4 step of (theta, theta'), templated so the
// identification's autodiff Jets flow through it; the simulator integrates its truth with it.
#pragma once

#include <cmath>

namespace storetrack::pendulum {

/// theta'' of the model at (theta, theta').
template <typename T>
T angular_acceleration(const T& omega0_sq, const T& gamma, const T& theta, const T& theta_dot) {
  using std::sin;
  return -gamma * theta_dot - omega0_sq * sin(theta);
}

/// Advances (theta, theta') by one classical RK4 step of length h.
template <typename T>
void rk4_step(const T& omega0_sq, const T& gamma, T& theta, T& theta_dot, const T& h) {
  const auto accel = [&](const T& a, const T& w) {
    return angular_acceleration(omega0_sq, gamma, a, w);
  };
  const T k1a = theta_dot, k1w = accel(theta, theta_dot);
  const T k2a = theta_dot + 0.5 * h * k1w;
  const T k2w = accel(theta + 0.5 * h * k1a, theta_dot + 0.5 * h * k1w);
  const T k3a = theta_dot + 0.5 * h * k2w;
  const T k3w = accel(theta + 0.5 * h * k2a, theta_dot + 0.5 * h * k2w);
  const T k4a = theta_dot + h * k3w, k4w = accel(theta + h * k3a, theta_dot + h * k3w);
  theta += h / 6.0 * (k1a + 2.0 * k2a + 2.0 * k3a + k4a);
  theta_dot += h / 6.0 * (k1w + 2.0 * k2w + 2.0 * k3w + k4w);
}

}  // namespace storetrack::pendulum
