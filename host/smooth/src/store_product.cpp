// The store-separation data product: kinematics at the CG and their first-order uncertainty
// (store_product.hpp; docs/post-processing.md, "Data product").
#include "storetrack/smooth/store_product.hpp"

#include <cmath>
#include <limits>

#include "storetrack/pose/body_pose.hpp"

namespace storetrack::smooth {

namespace {

using geometry::Mat3;
using geometry::skew;
using geometry::Vec3;
using ProductLoadings = Eigen::Matrix<double, kKinematicsSize, Eigen::Dynamic>;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// The kinematic quantities' shared loadings: the state's (E) through d_state, then the CG
/// offset's 3 whitened columns.
ProductLoadings shared_loadings(const SmoothedState& s, const KinematicsByState& d_state,
                                const KinematicsByCg& d_cg, double sigma_cg) {
  ProductLoadings L(kKinematicsSize, s.shared.cols() + 3);
  L.leftCols(s.shared.cols()) = d_state * s.shared;
  L.rightCols<3>() = d_cg * sigma_cg;
  return L;
}

/// The carriage state: the last of t0's segment before t0 - 2 u(t0); -1 when none.
int carriage_index(std::span<const SmoothedState> states, const ReleaseTime& release) {
  if (!release.detected) return -1;
  const auto limit = release.t0_ns - static_cast<time::TaiNs>(std::llround(2e9 * release.u_t0_s));
  int found = -1;
  for (std::size_t k = 0; k < states.size() && states[k].t_ns < limit; ++k)
    found = static_cast<int>(k);
  if (found < 0) return -1;
  // t0 must lie in the carriage state's segment (or the release is not in the smoothed data).
  for (std::size_t k = static_cast<std::size_t>(found) + 1; k < states.size(); ++k)
    if (states[k].t_ns >= release.t0_ns)
      return states[k].segment == states[static_cast<std::size_t>(found)].segment ? found : -1;
  return -1;
}

void set_nan(ProductSample& p, int row) {
  p.value.segment<3>(row).setConstant(kNaN);
  p.u_noise.segment<3>(row).setConstant(kNaN);
  p.u_shared.segment<3>(row).setConstant(kNaN);
}

/// The CG and Euler angles in aircraft axes: T_w_p (solved at this exposure) composed with the
/// state. A left perturbation (phi, rho) of T_w_p moves p_w by -[R_w_p p]x phi + rho and R_w_s
/// by phi; one of the state's attitude, delta, moves R_w_s by R_w_p delta.
void aircraft_rows(const SmoothedState& s, const PoseMeasurement& m, const KinematicsByState& J,
                   const ProductLoadings& state_shared, ProductSample& p) {
  const Mat3 R_w_p = m.T_w_p.linear();
  const Vec3 p_cg = p.value.segment<3>(kCgPosition);
  const Mat3 R_w_s = R_w_p * s.T_p_s.linear();
  const Mat3 J_ypr = pose::ypr_jacobian(R_w_s);
  p.value.segment<3>(kCgAircraft) = m.T_w_p * p_cg;
  p.value.segment<3>(kEulerAircraft) = geometry::ypr_from_rotation(R_w_s);
  geometry::Mat6 A = geometry::Mat6::Zero();  // by T_w_p's perturbation
  A.block<3, 3>(0, 0) = -skew(R_w_p * p_cg);
  A.block<3, 3>(0, 3).setIdentity();
  A.block<3, 3>(3, 0) = J_ypr;
  Eigen::Matrix<double, 6, kStateSize> B = Eigen::Matrix<double, 6, kStateSize>::Zero();
  B.topRows<3>() = R_w_p * J.middleRows<3>(kCgPosition);
  B.block<3, 3>(3, kAttitude) = J_ypr * R_w_p;
  const Eigen::Matrix<double, 6, 1> u_pylon =
      (A * m.pylon_cov_noise * A.transpose()).diagonal().cwiseMax(0).cwiseSqrt();
  const Eigen::Matrix<double, 6, 1> u_state =
      (B * s.cov_noise * B.transpose()).diagonal().cwiseMax(0).cwiseSqrt();
  p.u_noise.segment<6>(kCgAircraft) = u_pylon + u_state;
  // Shared: the state's (its CG rows already carry the CG offset's columns) plus T_w_p's.
  Eigen::Matrix<double, 6, Eigen::Dynamic> L(6, state_shared.cols());
  L.topRows<3>() = R_w_p * state_shared.middleRows<3>(kCgPosition);
  L.bottomRows<3>().setZero();
  L.bottomRows<3>().leftCols(s.shared.cols()) = J_ypr * R_w_p * s.shared.topRows<3>();
  L.leftCols(m.pylon_shared.cols()) += A * m.pylon_shared;
  p.u_shared.segment<6>(kCgAircraft) = L.rowwise().norm();
}

}  // namespace

const std::array<const char*, kProductSize> kProductNames = {
    "cg_x_m",    "cg_y_m",    "cg_z_m",    "yaw_rad",    "pitch_rad",    "roll_rad",
    "vx_m_s",    "vy_m_s",    "vz_m_s",    "ax_m_s2",    "ay_m_s2",      "az_m_s2",
    "p_rad_s",   "q_rad_s",   "r_rad_s",   "dcg_x_m",    "dcg_y_m",      "dcg_z_m",
    "cg_ac_x_m", "cg_ac_y_m", "cg_ac_z_m", "yaw_ac_rad", "pitch_ac_rad", "roll_ac_rad"};

KinematicsVector store_kinematics(const SmoothedState& s, const Vec3& cg_s,
                                  KinematicsByState* d_state, KinematicsByCg* d_cg) {
  const Mat3 R = s.T_p_s.linear();
  const Vec3 r = R * cg_s;  // the CG from the store origin, pylon axes
  const Vec3& w = s.angular_rate_p;
  const Vec3& alpha = s.angular_accel_p;
  // d/dt (R c) = w x R c; d^2/dt^2 = alpha x R c + w x (w x R c).
  const Mat3 K = skew(alpha) + skew(w) * skew(w);
  KinematicsVector out;
  out.segment<3>(kCgPosition) = s.T_p_s.translation() + r;
  out.segment<3>(kEulerYpr) = geometry::ypr_from_rotation(R);
  out.segment<3>(kCgVelocity) = s.velocity_p + w.cross(r);
  out.segment<3>(kCgAccel) = s.accel_p + K * r;
  out.segment<3>(kBodyRates) = R.transpose() * w;
  if (d_state) {
    // A left perturbation of the attitude moves r by -[r]x delta and R^T w by R^T [w]x delta.
    KinematicsByState& J = *d_state;
    J.setZero();
    J.block<3, 3>(kCgPosition, kAttitude) = -skew(r);
    J.block<3, 3>(kCgPosition, kPosition).setIdentity();
    J.block<3, 3>(kEulerYpr, kAttitude) = pose::ypr_jacobian(R);
    J.block<3, 3>(kCgVelocity, kAttitude) = -skew(w) * skew(r);
    J.block<3, 3>(kCgVelocity, kVelocity).setIdentity();
    J.block<3, 3>(kCgVelocity, kAngularRate) = -skew(r);
    J.block<3, 3>(kCgAccel, kAttitude) = -K * skew(r);
    J.block<3, 3>(kCgAccel, kAcceleration).setIdentity();
    J.block<3, 3>(kCgAccel, kAngularAccel) = -skew(r);
    J.block<3, 3>(kCgAccel, kAngularRate) = -skew(w.cross(r)) - skew(w) * skew(r);
    J.block<3, 3>(kBodyRates, kAttitude) = R.transpose() * skew(w);
    J.block<3, 3>(kBodyRates, kAngularRate) = R.transpose();
  }
  if (d_cg) {
    d_cg->setZero();
    d_cg->block<3, 3>(kCgPosition, 0) = R;
    d_cg->block<3, 3>(kCgVelocity, 0) = skew(w) * R;
    d_cg->block<3, 3>(kCgAccel, 0) = K * R;
  }
  return out;
}

std::vector<ProductSample> store_product(std::span<const SmoothedState> states,
                                         std::span<const PoseMeasurement> measurements,
                                         const ReleaseTime& release, const CgOffset& cg) {
  std::vector<ProductSample> out(states.size());
  std::vector<ProductLoadings> shared(states.size());
  KinematicsByState J;
  KinematicsByCg D;
  std::size_t next = 0;
  for (std::size_t k = 0; k < states.size(); ++k) {
    const SmoothedState& s = states[k];
    ProductSample& p = out[k];
    p.t_ns = s.t_ns;
    p.t_since_t0_s = release.detected ? static_cast<double>(s.t_ns - release.t0_ns) * 1e-9 : kNaN;
    p.segment = s.segment;
    p.measured = s.measured;
    p.step = s.step;
    p.value.head<kKinematicsSize>() = store_kinematics(s, cg.cg_s, &J, &D);
    p.u_noise.head<kKinematicsSize>() =
        (J * s.cov_noise * J.transpose()).diagonal().cwiseMax(0).cwiseSqrt();
    shared[k] = shared_loadings(s, J, D, cg.sigma_m);
    p.u_shared.head<kKinematicsSize>() = shared[k].rowwise().norm();
    // The exposure's own pylon pose (both in time order).
    while (next < measurements.size() && measurements[next].t_ns < s.t_ns)
      ++next;
    const bool pylon = next < measurements.size() && measurements[next].t_ns == s.t_ns &&
                       measurements[next].pylon_solved &&
                       measurements[next].pylon_shared.cols() <= s.shared.cols();
    if (pylon) {
      aircraft_rows(s, measurements[next], J, shared[k], p);
    } else {
      set_nan(p, kCgAircraft);
      set_nan(p, kEulerAircraft);
    }
  }
  const int c = carriage_index(states, release);
  for (std::size_t k = 0; k < states.size(); ++k) {
    ProductSample& p = out[k];
    if (c < 0) {
      set_nan(p, kCgDisplacement);
      continue;
    }
    const auto ci = static_cast<std::size_t>(c);
    p.value.segment<3>(kCgDisplacement) =
        p.value.segment<3>(kCgPosition) - out[ci].value.segment<3>(kCgPosition);
    p.u_noise.segment<3>(kCgDisplacement) =
        p.u_noise.segment<3>(kCgPosition) + out[ci].u_noise.segment<3>(kCgPosition);
    p.u_shared.segment<3>(kCgDisplacement) =
        (shared[k].middleRows<3>(kCgPosition) - shared[ci].middleRows<3>(kCgPosition))
            .rowwise()
            .norm();
  }
  return out;
}

}  // namespace storetrack::smooth
