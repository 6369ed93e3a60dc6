// Rigid transforms and the frame-naming rule of docs/conventions.md.
//
// A transform is named after both of its frames, T_a_b, and maps coordinates expressed in frame
// b into frame a:  p_a = T_a_b * p_b.  Composition chains on the inner letter:
// T_w_s = T_w_p * T_p_s.  Points carry their frame as a suffix: p_cam, p_pylon, p_world.
#pragma once

#include <algorithm>
#include <cmath>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace storetrack::geometry {

using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;
using Mat2 = Eigen::Matrix2d;
using Mat3 = Eigen::Matrix3d;
using Mat6 = Eigen::Matrix<double, 6, 6>;
using Vec6 = Eigen::Matrix<double, 6, 1>;

/// Rigid transform T_a_b (rotation R_a_b, translation t_a_b = origin of b expressed in a).
using Transform = Eigen::Isometry3d;

/// Skew-symmetric matrix [v]x, so that [v]x w = v x w.
inline Mat3 skew(const Vec3& v) {
  Mat3 m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

/// Exponential map of a rotation vector (axis * angle, rad) to a rotation matrix.
inline Mat3 rotation_from_rotvec(const Vec3& rotvec) {
  const double angle = rotvec.norm();
  if (angle < 1e-12) return Mat3::Identity() + skew(rotvec);
  return Eigen::AngleAxisd(angle, rotvec / angle).toRotationMatrix();
}

/// Logarithm map: rotation matrix to rotation vector (axis * angle, rad).
inline Vec3 rotvec_from_rotation(const Mat3& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.axis() * aa.angle();
}

/// Left Jacobian of SO(3) at rotation vector w: Exp(w + d) = Exp(J_l(w) d) Exp(w) to first order
/// (Barfoot, "State Estimation for Robotics", 2017, eq. 7.77). Turns a derivative with respect
/// to a left perturbation (below) into one with respect to the rotation vector itself.
inline Mat3 so3_left_jacobian(const Vec3& w) {
  const double theta = w.norm();
  const Mat3 W = skew(w);
  if (theta < 1e-6) return Mat3::Identity() + 0.5 * W + (1.0 / 6.0) * W * W;
  const double t2 = theta * theta;
  return Mat3::Identity() + (1 - std::cos(theta)) / t2 * W +
         (theta - std::sin(theta)) / (t2 * theta) * W * W;
}

/// Small-perturbation convention used for every 6x6 pose covariance in storetrack:
/// T_true = exp([delta_rot, delta_trans]) applied on the LEFT, i.e.
///   R_true = Exp(delta_rot) * R,  t_true = t + delta_trans,
/// with the 6-vector ordered (rx, ry, rz [rad], tx, ty, tz [m]) in the target frame a of T_a_b.
inline Transform perturb_left(const Transform& T_a_b, const Vec6& delta) {
  Transform out = T_a_b;
  out.linear() = rotation_from_rotvec(delta.head<3>()) * T_a_b.linear();
  out.translation() = T_a_b.translation() + delta.tail<3>();
  return out;
}

/// Its inverse: the delta with T_perturbed = perturb_left(T, delta) (a pose error against truth,
/// the step between two estimates), in the same (rotation, translation) order.
inline Vec6 left_difference(const Transform& T_perturbed, const Transform& T) {
  Vec6 delta;
  delta.head<3>() = rotvec_from_rotation(T_perturbed.linear() * T.linear().transpose());
  delta.tail<3>() = T_perturbed.translation() - T.translation();
  return delta;
}

/// Jacobians of the composition T_a_c = T_a_b T_b_c w.r.t. left perturbations (perturb_left) of
/// its factors: xi_ac = d_ac_d_ab xi_ab + d_ac_d_bc xi_bc (first order). With R_a_b <- Exp(phi)
/// R_a_b, t_a_b <- t_a_b + rho: phi_ac = phi, rho_ac = rho - [R_a_b t_b_c]x phi; with R_b_c <-
/// Exp(phi) R_b_c, t_b_c <- t_b_c + rho: phi_ac = R_a_b phi, rho_ac = R_a_b rho.
inline void composition_jacobians(const Transform& T_a_b, const Transform& T_b_c, Mat6& d_ac_d_ab,
                                  Mat6& d_ac_d_bc) {
  d_ac_d_ab.setIdentity();
  d_ac_d_ab.bottomLeftCorner<3, 3>() = -skew(T_a_b.linear() * T_b_c.translation());
  d_ac_d_bc.setZero();
  d_ac_d_bc.topLeftCorner<3, 3>() = T_a_b.linear();
  d_ac_d_bc.bottomRightCorner<3, 3>() = T_a_b.linear();
}

/// Builds T_a_b from a rotation vector (rad) and translation (m).
inline Transform make_transform(const Vec3& rotvec, const Vec3& translation) {
  Transform T = Transform::Identity();
  T.linear() = rotation_from_rotvec(rotvec);
  T.translation() = translation;
  return T;
}

/// Aerospace yaw-pitch-roll (Z-Y'-X'', rad) of a rotation R_a_b: R = Rz(yaw) Ry(pitch) Rx(roll).
inline Vec3 ypr_from_rotation(const Mat3& R) {
  const double pitch = std::asin(std::clamp(-R(2, 0), -1.0, 1.0));
  const double roll = std::atan2(R(2, 1), R(2, 2));
  const double yaw = std::atan2(R(1, 0), R(0, 0));
  return {yaw, pitch, roll};
}

inline Mat3 rotation_from_ypr(double yaw, double pitch, double roll) {
  return (Eigen::AngleAxisd(yaw, Vec3::UnitZ()) * Eigen::AngleAxisd(pitch, Vec3::UnitY()) *
          Eigen::AngleAxisd(roll, Vec3::UnitX()))
      .toRotationMatrix();
}

}  // namespace storetrack::geometry
