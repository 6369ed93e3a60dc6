// The pose filter's two steps that do not need the marks: starting at rest and predicting
// (Bar-Shalom et al. 2001, sec. 6.3.3). Its update by the marks is the matcher's
// (layouts.cpp, filter_update).
#include "storetrack/match/body_motion.hpp"

#include "storetrack/geometry/transform.hpp"

namespace storetrack::match {

using geometry::Mat3;
using geometry::Mat6;

PoseFilter PoseFilter::at_rest(double t_s, const geometry::Transform& T_w_b, const Mat6& pose_cov,
                               double angular_rate_sigma_radps, double velocity_sigma_mps) {
  PoseFilter f;
  f.valid = true;
  f.t_s = t_s;
  f.T_w_b = T_w_b;
  f.P.topLeftCorner<6, 6>() = pose_cov;
  const double wr = angular_rate_sigma_radps, vr = velocity_sigma_mps;
  f.P.block<3, 3>(6, 6) = wr * wr * Mat3::Identity();
  f.P.block<3, 3>(9, 9) = vr * vr * Mat3::Identity();
  return f;
}

PoseFilter PoseFilter::predicted(double to_s, double angular_accel_sigma_radps2,
                                 double accel_sigma_mps2) const {
  const double dt = to_s - t_s;
  PoseFilter p = *this;
  p.t_s = to_s;
  p.T_w_b.linear() = geometry::rotation_from_rotvec(omega_w * dt) * T_w_b.linear();
  p.T_w_b.translation() = T_w_b.translation() + v_w * dt;
  // F = [I dt*I; 0 I] over (pose, rates): F P F^T by 6x6 blocks.
  const Mat6 Ppp = P.topLeftCorner<6, 6>(), Ppr = P.topRightCorner<6, 6>(),
             Prr = P.bottomRightCorner<6, 6>();
  p.P.topLeftCorner<6, 6>() = Ppp + dt * (Ppr + Ppr.transpose()) + dt * dt * Prr;
  p.P.topRightCorner<6, 6>() = Ppr + dt * Prr;
  p.P.bottomLeftCorner<6, 6>() = p.P.topRightCorner<6, 6>().transpose();
  Mat12 Q = Mat12::Zero();
  const double qa = angular_accel_sigma_radps2 * angular_accel_sigma_radps2;
  const double ql = accel_sigma_mps2 * accel_sigma_mps2;
  const double d2 = dt * dt, d3 = d2 * dt, d4 = d3 * dt;
  for (int i = 0; i < 3; ++i) {
    Q(i, i) = qa * d4 / 4;
    Q(i, 6 + i) = Q(6 + i, i) = qa * d3 / 2;
    Q(6 + i, 6 + i) = qa * d2;
    Q(3 + i, 3 + i) = ql * d4 / 4;
    Q(3 + i, 9 + i) = Q(9 + i, 3 + i) = ql * d3 / 2;
    Q(9 + i, 9 + i) = ql * d2;
  }
  p.P += Q;
  return p;
}

}  // namespace storetrack::match
