#include "storetrack/triangulate/triangulate.hpp"

#include <cmath>

#include <Eigen/Cholesky>

#include "storetrack/uncertainty/spd_inverse.hpp"

namespace storetrack::triangulate {

using geometry::Mat3;
using geometry::Vec2;
using geometry::Vec3;

std::optional<Vec3> triangulate_linear(std::span<const Observation> observations) {
  // Each view gives two linear equations in X from x (r3.X' + t3) = r1.X' + t1 (and y), with
  // X' = X + displacement. Solved as weighted linear least squares (normal equations, 3x3):
  // rows are scaled by f/sigma so that they are approximately in units of pixel noise.
  Mat3 A = Mat3::Zero();
  Vec3 b = Vec3::Zero();
  int used = 0;
  for (const Observation& obs : observations) {
    if (obs.model == nullptr) continue;
    const auto xy = obs.model->unproject(obs.pixel_px);
    if (!xy) continue;
    const Mat3 R = obs.T_c_w.linear();
    const Vec3 t = obs.T_c_w.translation() + R * obs.displacement_w;
    const double w = obs.model->intrinsics().fx / std::max(obs.sigma_px, 1e-6);
    for (int row = 0; row < 2; ++row) {
      const double m = (*xy)(row);
      const Vec3 a = (m * R.row(2) - R.row(row)).transpose() * w;
      const double rhs = (t(row) - m * t(2)) * w;
      A.noalias() += a * a.transpose();
      b += a * rhs;
    }
    ++used;
  }
  if (used < 2) return std::nullopt;
  const Eigen::LDLT<Mat3> ldlt(A);
  if (ldlt.info() != Eigen::Success) return std::nullopt;
  // Rank check: two parallel rays leave A (near) singular.
  const Vec3 d = ldlt.vectorD().cwiseAbs();
  if (d.minCoeff() <= 1e-12 * d.maxCoeff()) return std::nullopt;
  Vec3 X = ldlt.solve(b);
  if (!X.allFinite()) return std::nullopt;
  return X;
}

namespace {

/// J^T W with the observation's pixel weight W: its information matrix, else sigma_px^-2 I
/// (a scalar product: the common case stays as cheap as before the matrix option).
Eigen::Matrix<double, 3, 2> weighted_transpose(const Observation& obs,
                                               const Eigen::Matrix<double, 2, 3>& J) {
  if (obs.information_px) return J.transpose() * *obs.information_px;
  return J.transpose() / (obs.sigma_px * obs.sigma_px);
}

/// Linearisation at X: H = sum J^T W J and g = sum J^T W r. `full` also fills out's residuals,
/// Jacobians (with the calibration's where options ask) and gains (J^T W for now).
bool linearise(std::span<const Observation> observations, const Options& options, const Vec3& X,
               bool full, bool at_start, Mat3& H, Vec3& g, Result& out) {
  H.setZero();
  g.setZero();
  if (full) {
    out.residual_px.resize(observations.size());
    out.jacobians.resize(observations.size());
    out.gain.resize(observations.size());
  }
  for (size_t i = 0; i < observations.size(); ++i) {
    const Observation& obs = observations[i];
    std::optional<Vec2> u;
    Eigen::Matrix<double, 2, 3> J;
    if (!full && at_start && obs.start != nullptr) {
      J = obs.start->d_pixel_d_point_w;
      u = obs.start->pixel_px + J * obs.displacement_w;
    } else if (!full) {
      Eigen::Matrix<double, 2, 3> J_cam;
      u = obs.model->project(obs.T_c_w * (X + obs.displacement_w), &J_cam);
      J = J_cam * obs.T_c_w.linear();
    } else if (options.calibration_jacobians) {
      u = obs.model->project_world(obs.T_c_w, X + obs.displacement_w, &out.jacobians[i]);
      J = out.jacobians[i].d_point_world;
    } else {
      u = obs.model->project(obs.T_c_w * (X + obs.displacement_w), &out.jacobians[i].d_point_cam);
      out.jacobians[i].d_point_world = out.jacobians[i].d_point_cam * obs.T_c_w.linear();
      J = out.jacobians[i].d_point_world;
    }
    if (!u) return false;
    const Vec2 r = obs.pixel_px - *u;
    const Eigen::Matrix<double, 3, 2> JtW = weighted_transpose(obs, J);
    H.noalias() += JtW * J;
    g.noalias() += JtW * r;
    if (full) {
      out.residual_px[i] = r;
      out.gain[i] = JtW;
    }
  }
  return true;
}

/// Gauss-Newton from X. The first pass projects only; the later ones linearise fully, since the
/// pass whose step is below the tolerance is the last: its Jacobians, gains and covariance are
/// kept (taken one step shorter than step_tolerance_m before the solution: a relative change
/// of that step over the depth) and its residuals moved by that step to first order (exact to
/// its square), which saves a projection pass. Converged on the first pass, or out of
/// iterations, a full pass at the solution follows. `from_start`: X is options.initial_p_w, so
/// the first pass may use the views' start projections.
bool refine(std::span<const Observation> observations, const Options& options, Vec3 X,
            bool from_start, Result& out) {
  const size_t n = observations.size();
  Mat3 H, H_inv;
  Vec3 g;
  bool full = false, converged = false;
  int it = 0;
  for (; it < options.max_iterations && !converged; ++it) {
    full = it > 0;
    if (!linearise(observations, options, X, full, from_start && it == 0, H, g, out)) return false;
    // H is symmetric positive definite unless the rays are degenerate (then this fails).
    if (!uncertainty::inverse_spd<3>(H, H_inv)) return false;
    const Vec3 step = H_inv * g;
    if (!step.allFinite()) return false;
    X += step;
    converged = step.norm() < options.step_tolerance_m;
    if (converged && full)
      for (size_t i = 0; i < n; ++i)
        out.residual_px[i] -= out.jacobians[i].d_point_world * step;
  }
  if (!(converged && full)) {
    if (!linearise(observations, options, X, true, false, H, g, out)) return false;
    if (!uncertainty::inverse_spd<3>(H, H_inv)) return false;
  }
  out.chi2 = 0;
  for (size_t i = 0; i < n; ++i) {
    const Vec2& r = out.residual_px[i];
    const auto& info = observations[i].information_px;
    out.chi2 += info ? r.dot(*info * r)
                     : r.squaredNorm() / (observations[i].sigma_px * observations[i].sigma_px);
  }
  out.cov_weighted = H_inv;
  bool sigma_weights = true;
  for (size_t i = 0; i < n; ++i) {
    out.gain[i] = out.cov_weighted * out.gain[i];
    sigma_weights = sigma_weights && !observations[i].information_px;
  }
  if (sigma_weights) {
    out.cov_centroid = out.cov_weighted;
  } else {
    out.cov_centroid.setZero();
    for (size_t i = 0; i < n; ++i) {
      const double s2 = observations[i].sigma_px * observations[i].sigma_px;
      out.cov_centroid.noalias() += s2 * out.gain[i] * out.gain[i].transpose();
    }
  }
  out.p_w = X;
  out.iterations = it;
  return out.p_w.allFinite() && out.cov_weighted.allFinite();
}

}  // namespace

bool triangulate(std::span<const Observation> observations, const Options& options, Result& out) {
  if (options.initial_p_w && options.initial_p_w->allFinite() &&
      refine(observations, options, *options.initial_p_w, true, out))
    return true;
  const auto init = triangulate_linear(observations);
  return init && refine(observations, options, *init, false, out);
}

}  // namespace storetrack::triangulate
