// The pendulum model shared by the identification (Jets) and the reference trajectory
// (doubles): the angle from the ODE and a mark's world position.
#pragma once

#include <cmath>
#include <cstddef>
#include <vector>

#include "storetrack/pendulum/pendulum_ode.hpp"

namespace storetrack::eval::detail {

/// Integration step [s]: RK4's global error at omega <= 10 rad/s is ~1e-9 rad over seconds.
constexpr double kOdeStepS = 5e-4;

inline double scalar_of(double x) {
  return x;
}
template <typename Jet>
double scalar_of(const Jet& x) {
  return x.a;
}

/// theta'' = -gamma theta' - omega0_sq sin(theta), from rest at theta0 for tau > 0 (held at
/// theta0 for tau <= 0). `tau` ascending (time since release); RK4 on the grid j * kOdeStepS and
/// one partial step to each tau (so derivatives with respect to the release time flow).
template <typename T>
void integrate_pendulum(const T& omega0_sq, const T& gamma, const T& theta0,
                        const std::vector<T>& tau, std::vector<T>& theta,
                        std::vector<T>& theta_dot) {
  const auto step = [&](T& a, T& w, const T& h) { pendulum::rk4_step(omega0_sq, gamma, a, w, h); };
  theta.resize(tau.size());
  theta_dot.resize(tau.size());
  T grid_a = theta0, grid_w = T(0.0);
  long grid = 0;  // grid_a, grid_w hold the state at tau = grid * kOdeStepS
  for (std::size_t i = 0; i < tau.size(); ++i) {
    if (scalar_of(tau[i]) <= 0) {
      theta[i] = theta0;
      theta_dot[i] = T(0.0);
      continue;
    }
    const long target = static_cast<long>(std::floor(scalar_of(tau[i]) / kOdeStepS));
    for (; grid < target; ++grid)
      step(grid_a, grid_w, T(kOdeStepS));
    T a = grid_a, w = grid_w;
    const T h = tau[i] - static_cast<double>(grid) * kOdeStepS;
    step(a, w, h);
    theta[i] = a;
    theta_dot[i] = w;
  }
}

/// World position of a mark at pendulum angle theta: pivot c, plane normal n (unit), gravity
/// direction `down` (unit), mark radius r, angle phi from the centre-of-mass line, offset h.
template <typename T>
void mark_position(const T* c, const T* n, const double* down, const T& r, const T& phi, const T& h,
                   const T& theta, T* p) {
  using std::cos;
  using std::sin;
  using std::sqrt;
  const T dn = n[0] * down[0] + n[1] * down[1] + n[2] * down[2];
  T e1[3] = {down[0] - dn * n[0], down[1] - dn * n[1], down[2] - dn * n[2]};
  const T norm = sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2]);
  for (T& v : e1)
    v /= norm;
  const T e2[3] = {n[1] * e1[2] - n[2] * e1[1], n[2] * e1[0] - n[0] * e1[2],
                   n[0] * e1[1] - n[1] * e1[0]};
  const T ca = r * cos(theta + phi), sa = r * sin(theta + phi);
  for (int k = 0; k < 3; ++k)
    p[k] = c[k] + ca * e1[k] + sa * e2[k] + h * n[k];
}

}  // namespace storetrack::eval::detail
