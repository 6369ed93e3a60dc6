#include "storetrack/pose/body_pose.hpp"

#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/SVD>

#include "storetrack/uncertainty/spd_inverse.hpp"

namespace storetrack::pose {

using geometry::Mat3;
using geometry::Mat6;
using geometry::Vec3;
using geometry::Vec6;

bool absolute_orientation(PointsInBody q_body_in, PointsInWorld p_world_in,
                          std::span<const double> weights, geometry::Transform& T_w_b) {
  const std::span<const Vec3> q_body = q_body_in.points, p_world = p_world_in.points;
  const size_t n = q_body.size();
  if (n < 3 || p_world.size() != n || weights.size() != n) return false;
  double wsum = 0;
  Vec3 q_mean = Vec3::Zero(), p_mean = Vec3::Zero();
  for (size_t i = 0; i < n; ++i) {
    wsum += weights[i];
    q_mean += weights[i] * q_body[i];
    p_mean += weights[i] * p_world[i];
  }
  if (!(wsum > 0)) return false;
  q_mean /= wsum;
  p_mean /= wsum;
  Mat3 cross = Mat3::Zero();  // sum w (p - p_mean)(q - q_mean)^T
  for (size_t i = 0; i < n; ++i)
    cross.noalias() += weights[i] * (p_world[i] - p_mean) * (q_body[i] - q_mean).transpose();
  const Eigen::JacobiSVD<Mat3> svd(cross, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Vec3 s = svd.singularValues();
  if (!(s(1) > 1e-12 * std::max(s(0), 1e-300))) return false;  // collinear marks
  Mat3 D = Mat3::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) D(2, 2) = -1;
  const Mat3 R = svd.matrixU() * D * svd.matrixV().transpose();
  T_w_b = geometry::Transform::Identity();
  T_w_b.linear() = R;
  T_w_b.translation() = p_mean - R * q_mean;
  return true;
}

bool fit_body(PointsInBody q_body_in, PointsInWorld p_world_in, std::span<const Mat3> cov_w,
              std::span<const double> survey_sigma_m, BodyFit& out, int max_iterations) {
  const std::span<const Vec3> q_body = q_body_in.points, p_world = p_world_in.points;
  const size_t n = q_body.size();
  if (n < 3 || p_world.size() != n || cov_w.size() != n || survey_sigma_m.size() != n) return false;
  // `out`'s lists keep their storage from fit to fit (the per-exposure path allocates nothing).
  std::vector<double>& weights = out.start_weight;
  weights.resize(n);
  for (size_t i = 0; i < n; ++i)
    weights[i] = 1.0 / (cov_w[i].trace() / 3.0 + survey_sigma_m[i] * survey_sigma_m[i]);
  geometry::Transform T;
  if (!absolute_orientation(q_body_in, p_world_in, weights, T)) return false;

  // Weights: inverse of each mark's total covariance. Survey errors are isotropic in the body
  // frame, so R sigma^2 I R^T = sigma^2 I.
  std::vector<Mat3>& W = out.weight;
  W.resize(n);
  for (size_t i = 0; i < n; ++i) {
    const Mat3 C = cov_w[i] + survey_sigma_m[i] * survey_sigma_m[i] * Mat3::Identity();
    if (!uncertainty::inverse_spd<3>(C, W[i])) return false;
  }

  // r_m = p_m - (Exp(phi) R q_m + t + rho):  J_m = [S_m, -I] with S_m = [R q_m]x, so
  // J^T W J = [[S^T W S, -S^T W], [-W S, W]] and J^T W r = [S^T W r; -W r] (3x3 blocks only).
  auto accumulate = [&](size_t i, Mat6& H, Vec6* g) {
    const Mat3 S = geometry::skew(T.linear() * q_body[i]);
    const Mat3 StW = S.transpose() * W[i];  // W symmetric: (W S)^T = S^T W
    H.topLeftCorner<3, 3>().noalias() += StW * S;
    H.topRightCorner<3, 3>() -= StW;
    H.bottomRightCorner<3, 3>() += W[i];
    if (g != nullptr) {
      const Vec3 Wr = W[i] * (p_world[i] - T * q_body[i]);
      g->head<3>().noalias() += S.transpose() * Wr;
      g->tail<3>() -= Wr;
    }
  };
  auto symmetrise = [](Mat6& H) {
    H.bottomLeftCorner<3, 3>() = H.topRightCorner<3, 3>().transpose();
  };
  // Gauss-Newton. The normal matrix of the pass whose step is below the tolerance is kept for
  // the covariance (taken one step of < 1e-7 rad and m before the solution: a relative change of
  // that order) instead of a further pass at the solution; out of iterations, one follows.
  Mat6 H;
  int it = 0;
  bool converged = false;
  for (; it < max_iterations && !converged; ++it) {
    H.setZero();
    Vec6 g = Vec6::Zero();
    for (size_t i = 0; i < n; ++i)
      accumulate(i, H, &g);
    symmetrise(H);
    // Gauss-Newton: H step = -J^T W r (H = J^T W J: positive definite for >= 3 non-collinear).
    Vec6 step;
    if (!uncertainty::solve_spd<6>(H, Vec6(-g), step)) return false;
    T = geometry::perturb_left(T, step);
    // The steps shrink linearly (non-zero residuals), by ~1e-4 per iteration here: after one
    // of < 1e-7 rad and m the solution is ~1e-11 away, 1e-7 of any pose's uncertainty (and still
    // 1e-5 of it were the steps to shrink by only 1e-2).
    converged = step.head<3>().norm() < 1e-7 && step.tail<3>().norm() < 1e-7;
  }
  if (!converged) {
    H.setZero();
    for (size_t i = 0; i < n; ++i)
      accumulate(i, H, nullptr);
    symmetrise(H);
  }
  // Residuals at the solution.
  out.residual_w.resize(n);
  out.chi2 = 0;
  for (size_t i = 0; i < n; ++i) {
    out.residual_w[i] = p_world[i] - T * q_body[i];
    out.chi2 += out.residual_w[i].dot(W[i] * out.residual_w[i]);
  }
  Mat6 H_inv;
  if (!uncertainty::inverse_spd<6>(H, H_inv)) return false;
  out.d_pose_d_point.resize(n);
  out.d_pose_d_survey.resize(n);
  const Mat3 R = T.linear();
  for (size_t i = 0; i < n; ++i) {
    // dxi/dp_m = -H^-1 J_m^T W_m with J_m^T W_m = [S_m^T W_m; -W_m].
    const Mat3 S = geometry::skew(R * q_body[i]);
    Mat63 JtW;
    JtW.topRows<3>().noalias() = S.transpose() * W[i];
    JtW.bottomRows<3>() = -W[i];
    out.d_pose_d_point[i].noalias() = -H_inv * JtW;
    out.d_pose_d_survey[i].noalias() = -out.d_pose_d_point[i] * R;
  }
  out.T_w_b = T;
  out.normal_matrix = H;
  out.normal_matrix_inverse = H_inv;
  out.iterations = it;
  return true;
}

void relative_pose_jacobians(const geometry::Transform& T_w_p, const geometry::Transform& T_w_s,
                             Mat6& d_ps_d_p, Mat6& d_ps_d_s) {
  // T_p_s = (R_p^T R_s, R_p^T (t_s - t_p)). With R_p <- Exp(phi_p) R_p, t_p <- t_p + rho_p (and
  // the same for s), to first order:
  //   phi_ps = R_p^T (phi_s - phi_p)
  //   rho_ps = R_p^T (rho_s - rho_p) + R_p^T [t_s - t_p]x phi_p
  const Mat3 Rpt = T_w_p.linear().transpose();
  const Vec3 d = T_w_s.translation() - T_w_p.translation();
  d_ps_d_p.setZero();
  d_ps_d_s.setZero();
  d_ps_d_p.topLeftCorner<3, 3>() = -Rpt;
  d_ps_d_p.bottomLeftCorner<3, 3>() = Rpt * geometry::skew(d);
  d_ps_d_p.bottomRightCorner<3, 3>() = -Rpt;
  d_ps_d_s.topLeftCorner<3, 3>() = Rpt;
  d_ps_d_s.bottomRightCorner<3, 3>() = Rpt;
}

Mat3 ypr_jacobian(const Mat3& R) {
  // R = Rz(y) Ry(p) Rx(r); a left (spatial) perturbation phi = E d(ypr) with
  // E = [e_z, Rz(y) e_y, Rz(y) Ry(p) e_x], so d(ypr)/dphi = E^-1 (singular at pitch = +-90 deg).
  const Vec3 ypr = geometry::ypr_from_rotation(R);
  const double cy = std::cos(ypr(0)), sy = std::sin(ypr(0));
  const double cp = std::cos(ypr(1)), sp = std::sin(ypr(1));
  Mat3 E;
  E.col(0) = Vec3::UnitZ();
  E.col(1) = Vec3(-sy, cy, 0);
  E.col(2) = Vec3(cy * cp, sy * cp, -sp);
  return E.inverse();
}

}  // namespace storetrack::pose
