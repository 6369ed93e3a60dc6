// The store-separation data product: kinematics at the CG and their first-order uncertainty
// (store_product.hpp; docs/post-processing.md, "Data product").
#include "storetrack/smooth/store_product.hpp"

#include <array>
#include <cmath>
#include <limits>
#include <utility>

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

/// A quantity in pylon axes as `aircraft_vector` turns it: its value, its noise covariances
/// (parts whose correlation is not stated: their standard deviations add, the safe side) and
/// its shared loadings (the product's columns: the recording's factors, then the CG offset's).
struct PylonAxesVector {
  Vec3 value = Vec3::Zero();
  std::array<Mat3, 2> cov_noise = {Mat3::Zero(), Mat3::Zero()};
  Eigen::Matrix<double, 3, Eigen::Dynamic> shared;
};

/// `q` in aircraft axes, R_w_p q (+ t_w_p for a point), with T_w_p solved at this exposure. A
/// left perturbation (phi, rho) of T_w_p moves it by -[R_w_p q]x phi (+ rho for a point): its
/// noise part adds to q's as a bound (T_p_s's noise holds the pylon's centroid noise of the
/// same exposures), its loadings on the same shared factors add exactly.
void aircraft_vector(const PylonAxesVector& q, bool point, const PoseMeasurement& m, int row,
                     ProductSample& p) {
  const Mat3 R = m.T_w_p.linear();
  const Vec3 turned = R * q.value;
  p.value.segment<3>(row) = point ? Vec3(turned + m.T_w_p.translation()) : turned;
  Eigen::Matrix<double, 3, 6> A = Eigen::Matrix<double, 3, 6>::Zero();
  A.leftCols<3>() = -skew(turned);
  if (point) A.rightCols<3>().setIdentity();
  Vec3 u = (A * m.pylon_cov_noise * A.transpose()).diagonal().cwiseMax(0).cwiseSqrt();
  for (const Mat3& C : q.cov_noise)
    u += (R * C * R.transpose()).diagonal().cwiseMax(0).cwiseSqrt();
  p.u_noise.segment<3>(row) = u;
  Eigen::Matrix<double, 3, Eigen::Dynamic> L = R * q.shared;
  L.leftCols(m.pylon_shared.cols()) += A * m.pylon_shared;
  p.u_shared.segment<3>(row) = L.rowwise().norm();
}

/// Rows `row` of the kinematics as a pylon-axes vector (noise J P J^T, loadings `shared`).
PylonAxesVector kinematics_rows(const SmoothedState& s, const KinematicsByState& J,
                                const ProductLoadings& shared, int row) {
  PylonAxesVector q;
  const Eigen::Matrix<double, 3, kStateSize> Jr = J.middleRows<3>(row);
  q.cov_noise[0] = Jr * s.cov_noise * Jr.transpose();
  q.shared = shared.middleRows<3>(row);
  return q;
}

/// The Euler angles of R_w_s = R_w_p R_p_s: a left perturbation phi of T_w_p moves R_w_s by
/// phi, one of the state's attitude, delta, by R_w_p delta.
void aircraft_euler(const SmoothedState& s, const PoseMeasurement& m, ProductSample& p) {
  const Mat3 R_w_p = m.T_w_p.linear();
  const Mat3 R_w_s = R_w_p * s.T_p_s.linear();
  const Mat3 J_ypr = pose::ypr_jacobian(R_w_s);
  p.value.segment<3>(kEulerAircraft) = geometry::ypr_from_rotation(R_w_s);
  const Mat3 B = J_ypr * R_w_p;
  const Vec3 u_pylon =
      (J_ypr * m.pylon_cov_noise.topLeftCorner<3, 3>() * J_ypr.transpose()).diagonal();
  const Vec3 u_state =
      (B * s.cov_noise.block<3, 3>(kAttitude, kAttitude) * B.transpose()).diagonal();
  p.u_noise.segment<3>(kEulerAircraft) =
      u_pylon.cwiseMax(0).cwiseSqrt() + u_state.cwiseMax(0).cwiseSqrt();
  Eigen::Matrix<double, 3, Eigen::Dynamic> L = B * s.shared.topRows<3>();
  L.leftCols(m.pylon_shared.cols()) += J_ypr * m.pylon_shared.topRows<3>();
  p.u_shared.segment<3>(kEulerAircraft) = L.rowwise().norm();
}

/// The CG, Euler angles, CG velocity and acceleration and the angular rate in aircraft axes.
void aircraft_rows(const SmoothedState& s, const PoseMeasurement& m, const KinematicsByState& J,
                   const ProductLoadings& shared, ProductSample& p) {
  PylonAxesVector cg = kinematics_rows(s, J, shared, kCgPosition);
  cg.value = p.value.segment<3>(kCgPosition);
  aircraft_vector(cg, true, m, kCgAircraft, p);
  aircraft_euler(s, m, p);
  for (const auto& [from, to] :
       {std::pair{kCgVelocity, kCgVelocityAircraft}, std::pair{kCgAccel, kCgAccelAircraft}}) {
    PylonAxesVector q = kinematics_rows(s, J, shared, from);
    q.value = p.value.segment<3>(from);
    aircraft_vector(q, false, m, to, p);
  }
  PylonAxesVector w;  // the state's own rows (no CG columns: they load zero)
  w.value = s.angular_rate_p;
  w.cov_noise[0] = s.cov_noise.block<3, 3>(kAngularRate, kAngularRate);
  w.shared = Eigen::Matrix<double, 3, Eigen::Dynamic>::Zero(3, shared.cols());
  w.shared.leftCols(s.shared.cols()) = s.shared.middleRows<3>(kAngularRate);
  aircraft_vector(w, false, m, kAngularRateAircraft, p);
}

}  // namespace

const std::array<const char*, kProductSize> kProductNames = {
    "cg_x_m",      "cg_y_m",      "cg_z_m",      "yaw_rad",    "pitch_rad",    "roll_rad",
    "vx_m_s",      "vy_m_s",      "vz_m_s",      "ax_m_s2",    "ay_m_s2",      "az_m_s2",
    "p_rad_s",     "q_rad_s",     "r_rad_s",     "dcg_x_m",    "dcg_y_m",      "dcg_z_m",
    "cg_ac_x_m",   "cg_ac_y_m",   "cg_ac_z_m",   "yaw_ac_rad", "pitch_ac_rad", "roll_ac_rad",
    "vx_ac_m_s",   "vy_ac_m_s",   "vz_ac_m_s",   "ax_ac_m_s2", "ay_ac_m_s2",   "az_ac_m_s2",
    "wx_ac_rad_s", "wy_ac_rad_s", "wz_ac_rad_s", "dcg_ac_x_m", "dcg_ac_y_m",   "dcg_ac_z_m"};

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
  std::vector<Mat3> cg_noise(states.size());
  std::vector<const PoseMeasurement*> pylon(states.size(), nullptr);
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
    const Eigen::Matrix<double, 3, kStateSize> J_cg = J.middleRows<3>(kCgPosition);
    cg_noise[k] = J_cg * s.cov_noise * J_cg.transpose();
    // The exposure's own pylon pose (both in time order).
    while (next < measurements.size() && measurements[next].t_ns < s.t_ns)
      ++next;
    if (next < measurements.size() && measurements[next].t_ns == s.t_ns &&
        measurements[next].pylon_solved &&
        measurements[next].pylon_shared.cols() <= s.shared.cols())
      pylon[k] = &measurements[next];
    if (pylon[k]) {
      aircraft_rows(s, *pylon[k], J, shared[k], p);
    } else {
      for (const int row : {kCgAircraft, kEulerAircraft, kCgVelocityAircraft, kCgAccelAircraft,
                            kAngularRateAircraft})
        set_nan(p, row);
    }
  }
  const int c = carriage_index(states, release);
  for (std::size_t k = 0; k < states.size(); ++k) {
    ProductSample& p = out[k];
    if (c < 0) {
      set_nan(p, kCgDisplacement);
      set_nan(p, kCgDisplacementAircraft);
      continue;
    }
    const auto ci = static_cast<std::size_t>(c);
    // The smoother states no covariance between two times: the two noise parts' standard
    // deviations add (the bound), per pylon axis here and per aircraft axis below.
    PylonAxesVector d;
    d.value = p.value.segment<3>(kCgPosition) - out[ci].value.segment<3>(kCgPosition);
    d.cov_noise = {cg_noise[k], cg_noise[ci]};
    d.shared = shared[k].middleRows<3>(kCgPosition) - shared[ci].middleRows<3>(kCgPosition);
    p.value.segment<3>(kCgDisplacement) = d.value;
    p.u_noise.segment<3>(kCgDisplacement) =
        p.u_noise.segment<3>(kCgPosition) + out[ci].u_noise.segment<3>(kCgPosition);
    p.u_shared.segment<3>(kCgDisplacement) = d.shared.rowwise().norm();
    if (pylon[k])
      aircraft_vector(d, false, *pylon[k], kCgDisplacementAircraft, p);
    else
      set_nan(p, kCgDisplacementAircraft);
  }
  return out;
}

}  // namespace storetrack::smooth
