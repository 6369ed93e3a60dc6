// BodyMotion: the one motion state the host keeps of a rigid body (issue 29). Whatever carries
// a body's motion from one exposure to the next is here, and nothing else keeps any:
//  - `filter`: the constant-velocity pose filter in the world frame (Bar-Shalom et al. 2001,
//    sec. 6.3.3). The matcher writes it when it identifies the body's marks; it predicts the
//    marks for the gates and tells when the body is lost.
//  - `last_world`: the processor's last solved pose of the body in the world, with its time:
//    the start of the next resection when the matcher has no pose of its own for the body
//    (marks given by id, or seen by single cameras only).
//  - `last_solved`, `previous_solved`: the processor's last two solutions of the body in the
//    frame its sample states (the store relative to the pylon), with their uncertainty by
//    source and loadings. PoseTracker extrapolates the sample from them over a short gap.
//  - `first_motion_ns`: when the body first moved away from its reference (the release), which
//    sets the extrapolation's acceleration model (docs/uncertainty.md, "Release zone").
// Two estimates of one motion, on purpose and side by side: the gate needs a prediction bounded
// by the largest plausible accelerations whatever the calibration (a filter of the matcher's
// own fits), the sample an honest one split by source (differences of solved poses whose
// shared calibration errors cancel). The matcher owns the bodies' states
// (MarkMatcher::motion()) and resets them together (MarkMatcher::reset_tracking()).
#pragma once

#include <cmath>
#include <limits>
#include <optional>
#include <utility>

#include <Eigen/Core>

#include "storetrack/geometry/transform.hpp"
#include "storetrack/pose/pose_result.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::match {

/// d p_w / d(left perturbation of T_w_b) for a body point p_b (R <- Exp(phi) R, t <- t + rho):
/// G = [S, I], S = -[R p_b]x.
inline Eigen::Matrix<double, 3, 6> point_pose_jacobian(const geometry::Transform& T_w_b,
                                                       const geometry::Vec3& p_b) {
  Eigen::Matrix<double, 3, 6> G;
  G.leftCols<3>() = -geometry::skew(T_w_b.linear() * p_b);
  G.rightCols<3>() = geometry::Mat3::Identity();
  return G;
}

/// Covariance of a body point T_w_b p_b under a pose covariance P: G P G^T with G =
/// point_pose_jacobian = [S, I], by blocks, (S P_rr + P_tr) S^T + S P_rt + P_tt (half the
/// products of the dense 3 x 6 form).
inline geometry::Mat3 point_covariance(const geometry::Transform& T_w_b, const geometry::Vec3& p_b,
                                       const geometry::Mat6& P) {
  const geometry::Mat3 S = point_pose_jacobian(T_w_b, p_b).leftCols<3>();
  const geometry::Mat3 S_P_rt = S * P.topRightCorner<3, 3>();
  const geometry::Mat3 Y = S * P.topLeftCorner<3, 3>() + P.bottomLeftCorner<3, 3>();
  return Y * S.transpose() + S_P_rt + P.bottomRightCorner<3, 3>();
}

/// Constant-velocity pose filter of a body (error state: left rotation perturbation,
/// translation, angular rate, velocity; all in the world frame).
struct PoseFilter {
  using Mat12 = Eigen::Matrix<double, 12, 12>;
  bool valid = false;
  double t_s = 0;  ///< the matcher's time (seconds since its time origin)
  geometry::Transform T_w_b = geometry::Transform::Identity();
  geometry::Vec3 omega_w = geometry::Vec3::Zero();  ///< angular rate [rad/s]
  geometry::Vec3 v_w = geometry::Vec3::Zero();      ///< velocity of the body origin [m/s]
  Mat12 P = Mat12::Zero();

  /// A body at pose T_w_b (6x6 covariance `pose_cov`) and at rest, its rates with their
  /// a-priori spread (standard uncertainties per axis): an acquisition from the prior pose or
  /// a (re-)acquisition by a layout fit.
  static PoseFilter at_rest(double t_s, const geometry::Transform& T_w_b,
                            const geometry::Mat6& pose_cov, double angular_rate_sigma_radps,
                            double velocity_sigma_mps);
  /// The filter extrapolated to t_s (discrete white-noise acceleration, per axis for rotation
  /// and translation, standard uncertainties of the accelerations given).
  PoseFilter predicted(double t_s, double angular_accel_sigma_radps2,
                       double accel_sigma_mps2) const;
};

/// A pose at a time.
struct TimedPose {
  bool valid = false;
  time::TaiNs t_ns = 0;
  geometry::Transform T = geometry::Transform::Identity();
};

/// A pose the processor solved from one exposure, with its uncertainty.
struct SolvedPose {
  bool valid = false;
  time::TaiNs t_ns = 0;
  pose::PoseResult pose;
};

struct BodyMotion {
  PoseFilter filter;
  TimedPose last_world;
  SolvedPose last_solved, previous_solved;
  /// Time of the body's first significant motion (min(): not yet seen).
  time::TaiNs first_motion_ns = std::numeric_limits<time::TaiNs>::min();

  /// Forgets everything (the next exposure starts from the prior pose).
  void reset() { *this = BodyMotion{}; }
  /// The last solved pose T_w_b if it is recent (|age| <= max_age_s) at time t_ns_now (no time,
  /// min(): none).
  std::optional<geometry::Transform> recent_world_pose(time::TaiNs t_ns_now,
                                                       double max_age_s) const {
    if (!last_world.valid || t_ns_now == std::numeric_limits<time::TaiNs>::min())
      return std::nullopt;
    const double age_s = static_cast<double>(t_ns_now - last_world.t_ns) * 1e-9;
    if (!(std::abs(age_s) <= max_age_s)) return std::nullopt;
    return last_world.T;
  }
  /// A solution of this exposure in the sample's frame: the older one is kept for the velocity.
  void record_solved(time::TaiNs t_ns, const pose::PoseResult& pose) {
    std::swap(previous_solved, last_solved);  // the older one's buffers take the new pose
    last_solved.valid = true;
    last_solved.t_ns = t_ns;
    last_solved.pose = pose;
  }
};

}  // namespace storetrack::match
