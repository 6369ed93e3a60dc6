// 6-DoF pose of a rigid body from its triangulated marks (docs/uncertainty.md).
//
// Initialisation: weighted absolute orientation (Umeyama, IEEE PAMI 13(4) 1991, with weights as
// in Horn, JOSA A 4(4) 1987), no scale. Refinement: Gauss-Newton on the Mahalanobis distances
// r_m = p_w,m - (R q_m + t) with each mark's 3x3 covariance (plus its survey sigma rotated into
// the world frame). Pose increments are LEFT perturbations (rx, ry, rz, tx, ty, tz)
// (docs/conventions.md). At the solution dxi/dp_m = -H^-1 J_m^T W_m and dxi/dq_m = -dxi/dp_m R,
// which propagate any (correlated) mark covariance to the pose.
#pragma once

#include <span>
#include <vector>

#include <Eigen/Core>

#include "storetrack/geometry/transform.hpp"

namespace storetrack::pose {

using Mat63 = Eigen::Matrix<double, 6, 3>;

/// The marks of one body in its own frame (the survey, q) and the same marks, in the same order,
/// measured in the world frame (p). Two types, so that a call with the two sets the wrong way
/// round does not compile (both are spans of Vec3; swapped, the fit returns T_b_w silently).
/// For a transform between two other frames, T_to_from: the "body" is the frame mapped from.
struct PointsInBody {
  std::span<const geometry::Vec3> points;
};
struct PointsInWorld {
  std::span<const geometry::Vec3> points;
};

/// Weighted absolute orientation: T_w_b minimising sum w_m |p_w,m - T_w_b q_m|^2.
/// Needs >= 3 non-collinear points; returns false otherwise.
bool absolute_orientation(PointsInBody q_body, PointsInWorld p_world,
                          std::span<const double> weights, geometry::Transform& T_w_b);

struct BodyFit {
  geometry::Transform T_w_b = geometry::Transform::Identity();
  geometry::Mat6 normal_matrix = geometry::Mat6::Zero();  ///< J^T W J at the solution
  /// Its inverse: the pose covariance the fit's own weights imply (block-diagonal marks).
  geometry::Mat6 normal_matrix_inverse = geometry::Mat6::Zero();
  std::vector<Mat63> d_pose_d_point;       ///< dxi/dp_w,m per mark (left perturbation)
  std::vector<Mat63> d_pose_d_survey;      ///< dxi/dq_m per mark
  std::vector<geometry::Vec3> residual_w;  ///< p_w,m - T_w_b q_m
  std::vector<geometry::Mat3> weight;      ///< W_m = (cov_w,m + sigma_m^2 I)^-1 per mark
  std::vector<double> start_weight;        ///< the starting absolute orientation's, per mark
  double chi2 = 0;                         ///< sum r^T W r (block-diagonal weights)
  int iterations = 0;
};

/// Fits T_w_b to marks with world covariances cov_w (3x3 each, the marks' total marginal
/// covariance) and isotropic survey sigmas. Returns false with < 3 marks or a singular fit.
bool fit_body(PointsInBody q_body, PointsInWorld p_world, std::span<const geometry::Mat3> cov_w,
              std::span<const double> survey_sigma_m, BodyFit& out, int max_iterations = 10);

/// Jacobians of T_p_s = T_w_p^-1 T_w_s w.r.t. left perturbations of T_w_p and T_w_s:
/// xi_ps = A_p xi_p + A_s xi_s (first order).
void relative_pose_jacobians(const geometry::Transform& T_w_p, const geometry::Transform& T_w_s,
                             geometry::Mat6& d_ps_d_p, geometry::Mat6& d_ps_d_s);

/// d(yaw, pitch, roll)/d(left rotation perturbation) of R (Z-Y'-X'', docs/conventions.md).
geometry::Mat3 ypr_jacobian(const geometry::Mat3& R);

}  // namespace storetrack::pose
