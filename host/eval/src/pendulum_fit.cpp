// The pendulum identification (Ceres): one residual block per run (every sample's 3-D position
// against the model, whitened by the host's stated 3x3 covariance: the triangulation's depth
// elongation is not along a world axis), shared L, gamma, pivot, normal and mark geometry,
// per-run theta0 and release time. The covariance, in the tangent space (the normal on its
// sphere, the first mark's offset fixed), per PendulumOptions::covariance_scale: by default the
// sandwich A^-1 B A^-1 (A = J^T J of the whitened Jacobian, B from the residuals clustered per
// exposure), which holds whatever the shape of the random errors against the stated weights.
#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <cmath>
#include <memory>

#include "pendulum_internal.hpp"
#include "pendulum_model.hpp"

namespace storetrack::eval {

using geometry::Vec3;

namespace {

/// Residuals of one run; parameter blocks: shared, run, pivot, normal, then its marks.
struct RunResidual {
  const detail::PreparedRun* run = nullptr;
  std::vector<int> block_of_slot;      ///< mark slot -> parameter block index (-1: not in the run)
  std::vector<geometry::Mat3> whiten;  ///< per sample: L^-1 with L L^T its stated covariance
  double g = 0;
  Vec3 down = Vec3::UnitZ();

  template <typename T>
  bool operator()(T const* const* p, T* residuals) const {
    std::vector<T> tau(run->times_s.size()), theta, theta_dot;
    for (size_t i = 0; i < tau.size(); ++i)
      tau[i] = T(run->times_s[i]) - p[1][1];
    detail::integrate_pendulum(T(g) / p[0][0], p[0][1], p[1][0], tau, theta, theta_dot);
    for (size_t i = 0; i < run->run->samples.size(); ++i) {
      const MarkSample& s = run->run->samples[i];
      const T* m = p[block_of_slot[static_cast<size_t>(run->mark_slot[i])]];
      T pos[3];
      detail::mark_position(p[2], p[3], down.data(), m[0], m[1], m[2],
                            theta[static_cast<size_t>(run->time_index[i])], pos);
      const geometry::Mat3& W = whiten[i];
      const T d[3] = {pos[0] - s.p_w(0), pos[1] - s.p_w(1), pos[2] - s.p_w(2)};
      for (int k = 0; k < 3; ++k)
        residuals[3 * i + static_cast<size_t>(k)] =
            W(k, 0) * d[0] + W(k, 1) * d[1] + W(k, 2) * d[2];
    }
    return true;
  }
};

/// L^-1 of the sample's stated covariance (the per-axis u when the file has no off-diagonal
/// terms, where cov_w is diagonal anyway).
geometry::Mat3 whitening(const MarkSample& s) {
  const geometry::Mat3 cov =
      s.full_covariance ? s.cov_w : geometry::Mat3(s.u_w.cwiseProduct(s.u_w).asDiagonal());
  const Eigen::LLT<geometry::Mat3> llt(cov);
  if (llt.info() != Eigen::Success)
    throw EvalInputError(s.line > 0 ? "line " + std::to_string(s.line) +
                                          ": the stated covariance is not positive definite"
                                    : "a sample's stated covariance is not positive definite");
  return llt.matrixL().solve(geometry::Mat3::Identity());
}

/// The solver's parameter blocks and where each one's tangent columns start in the Jacobian.
struct Blocks {
  std::vector<double*> order;
  std::vector<int> column;
  int columns = 0;
  void add(double* block, int tangent) {
    order.push_back(block);
    column.push_back(columns);
    columns += tangent;
  }
};

/// Returns the residual blocks in run order (the order of the evaluated residuals).
std::vector<ceres::ResidualBlockId> add_residual_blocks(
    ceres::Problem& problem, const std::vector<detail::PreparedRun>& runs,
    detail::PendulumState& st, const PendulumOptions& options) {
  std::vector<ceres::ResidualBlockId> ids;
  for (size_t r = 0; r < runs.size(); ++r) {
    auto* functor = new RunResidual;
    functor->run = &runs[r];
    functor->g = options.g_m_s2;
    functor->down = options.down_w.normalized();
    for (const MarkSample& sample : runs[r].run->samples)
      functor->whiten.push_back(whitening(sample));
    auto* cost = new ceres::DynamicAutoDiffCostFunction<RunResidual, 8>(functor);
    std::vector<double*> blocks = {st.shared.data(), st.run[r].data(), st.pivot.data(),
                                   st.normal.data()};
    for (int size : {2, 2, 3, 3})
      cost->AddParameterBlock(size);
    functor->block_of_slot.assign(st.mark_ids.size(), -1);
    std::vector<bool> present(st.mark_ids.size(), false);
    for (int s : runs[r].mark_slot)
      present[static_cast<size_t>(s)] = true;
    for (size_t m = 0; m < present.size(); ++m)
      if (present[m]) {
        functor->block_of_slot[m] = static_cast<int>(blocks.size());
        blocks.push_back(st.mark[m].data());
        cost->AddParameterBlock(3);
      }
    cost->SetNumResiduals(static_cast<int>(3 * runs[r].run->samples.size()));
    ids.push_back(problem.AddResidualBlock(cost, nullptr, blocks));
  }
  problem.SetManifold(st.normal.data(), new ceres::SphereManifold<3>);
  problem.SetManifold(st.mark[0].data(), new ceres::SubsetManifold(3, {2}));
  problem.SetParameterLowerBound(st.shared.data(), 0, 1e-3);
  return ids;
}

Blocks ordered_blocks(detail::PendulumState& st) {
  Blocks b;
  b.add(st.shared.data(), 2);
  for (auto& r : st.run)
    b.add(r.data(), 2);
  b.add(st.pivot.data(), 3);
  b.add(st.normal.data(), 2);
  for (size_t m = 0; m < st.mark.size(); ++m)
    b.add(st.mark[m].data(), m == 0 ? 2 : 3);
  return b;
}

Eigen::MatrixXd dense(const ceres::CRSMatrix& crs) {
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(crs.num_rows, crs.num_cols);
  for (int i = 0; i < crs.num_rows; ++i)
    for (int k = crs.rows[static_cast<size_t>(i)]; k < crs.rows[static_cast<size_t>(i) + 1]; ++k)
      J(i, crs.cols[static_cast<size_t>(k)]) = crs.values[static_cast<size_t>(k)];
  return J;
}

/// The sandwich A^-1 B A^-1 (Huber-White, clustered): B = sum over exposures of g g^T with
/// g = J_e^T r_e the gradient of one exposure's whitened residuals (its marks share the
/// cameras' trigger jitter), times the small-sample factor G/(G-1) (N-1)/(N-p) for G exposures,
/// N residuals and p parameters. It estimates the scatter of the random errors as they are,
/// where s^2 A^-1 assumes they have the stated covariance's shape up to one scale.
Eigen::MatrixXd observed_covariance(const std::vector<detail::PreparedRun>& runs,
                                    const Eigen::MatrixXd& J, const std::vector<double>& residuals,
                                    const Eigen::MatrixXd& A_inverse) {
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero(J.cols(), J.cols());
  Eigen::Index row = 0;
  long exposures = 0;
  for (const detail::PreparedRun& run : runs) {
    Eigen::MatrixXd gradient =
        Eigen::MatrixXd::Zero(J.cols(), static_cast<Eigen::Index>(run.times_s.size()));
    for (size_t i = 0; i < run.run->samples.size(); ++i, row += 3) {
      const Eigen::Vector3d r(residuals[static_cast<size_t>(row)],
                              residuals[static_cast<size_t>(row + 1)],
                              residuals[static_cast<size_t>(row + 2)]);
      gradient.col(run.time_index[i]) += J.middleRows(row, 3).transpose() * r;
    }
    B += gradient * gradient.transpose();
    exposures += static_cast<long>(run.times_s.size());
  }
  const double n = static_cast<double>(J.rows()), p = static_cast<double>(J.cols()),
               g = static_cast<double>(exposures);
  const double small_sample = g / (g - 1) * (n - 1) / (n - p);
  return small_sample * A_inverse * B * A_inverse;
}

double sigma(const Eigen::MatrixXd& C, int i) {
  return std::sqrt(std::max(0.0, C(i, i)));
}

/// Fills the parameters and their standard uncertainties.
void fill_parameters(const detail::PendulumState& st, const std::vector<detail::PreparedRun>& runs,
                     const Blocks& b, const Eigen::MatrixXd& C, const PendulumOptions& options,
                     PendulumResult& out) {
  out.equivalent_length_m = st.shared[0];
  out.equivalent_length_sigma_m = sigma(C, b.column[0]);
  out.damping_per_inertia_1_s = st.shared[1];
  out.damping_per_inertia_sigma_1_s = sigma(C, b.column[0] + 1);
  out.omega0_rad_s = std::sqrt(options.g_m_s2 / st.shared[0]);
  if (options.l1_m) {
    const double l1 = *options.l1_m, rel_l1 = options.l1_sigma_m / l1;
    const double rel_L = out.equivalent_length_sigma_m / out.equivalent_length_m;
    out.l2_m = std::sqrt(out.equivalent_length_m * l1);
    out.l2_sigma_m = *out.l2_m * 0.5 * std::hypot(rel_L, rel_l1);
    out.beta_per_mass_m2_s = out.damping_per_inertia_1_s * out.equivalent_length_m * l1;
    const double rel_g =
        out.damping_per_inertia_sigma_1_s / std::max(std::abs(out.damping_per_inertia_1_s), 1e-300);
    out.beta_per_mass_sigma_m2_s =
        std::abs(*out.beta_per_mass_m2_s) * std::hypot(rel_g, std::hypot(rel_L, rel_l1));
  }
  for (size_t r = 0; r < runs.size(); ++r) {
    PendulumRunEstimate e;
    e.path = runs[r].run->path;
    const int c = b.column[1 + r];
    e.theta0_rad = std::remainder(st.run[r][0], 2 * M_PI);
    e.theta0_sigma_rad = sigma(C, c);
    e.release_s = st.run[r][1];
    e.release_sigma_s = sigma(C, c + 1);
    e.release_tai_ns = runs[r].run->origin_tai_ns + std::llround(e.release_s * 1e9);
    e.clockwise = st.clockwise[r];
    e.exposures = static_cast<int>(runs[r].times_s.size());
    for (double t : runs[r].times_s)
      e.exposures_after_release += t > e.release_s ? 1 : 0;
    out.runs.push_back(e);
  }
  const size_t pivot_block = 1 + runs.size();
  const int cp = b.column[pivot_block], cn = b.column[pivot_block + 1];
  out.pivot_w = Vec3(st.pivot[0], st.pivot[1], st.pivot[2]);
  out.pivot_covariance = C.block(cp, cp, 3, 3);
  out.normal_w = Vec3(st.normal[0], st.normal[1], st.normal[2]).normalized();
  out.normal_sigma_rad = std::sqrt(std::max(0.0, C.block(cn, cn, 2, 2).trace()));
  for (size_t m = 0; m < st.mark.size(); ++m) {
    const int c = b.column[pivot_block + 2 + m];
    PendulumMarkEstimate e;
    e.mark_id = st.mark_ids[m];
    e.radius_m = st.mark[m][0];
    e.radius_sigma_m = sigma(C, c);
    e.angle_rad = std::remainder(st.mark[m][1], 2 * M_PI);
    e.angle_sigma_rad = sigma(C, c + 1);
    e.offset_m = st.mark[m][2];
    e.offset_sigma_m = m == 0 ? 0 : sigma(C, c + 2);
    out.marks.push_back(e);
  }
}

/// Per sample: measured - reference (= -u r), the reference's u from the covariance, the speed
/// and the distance from the reference camera's optical axis.
std::vector<detail::SampleError> sample_errors(const detail::PendulumState& st,
                                               const std::vector<detail::PreparedRun>& runs,
                                               const std::vector<double>& residuals,
                                               const Eigen::MatrixXd& J, const Eigen::MatrixXd& C,
                                               const PendulumOptions& options,
                                               PendulumResult& out) {
  std::vector<detail::SampleError> errors;
  Eigen::Index row = 0;
  for (size_t r = 0; r < runs.size(); ++r) {
    std::vector<double> theta, theta_dot, tau;
    for (double t : runs[r].times_s)
      tau.push_back(t - st.run[r][1]);
    detail::integrate_pendulum(options.g_m_s2 / st.shared[0], st.shared[1], st.run[r][0], tau,
                               theta, theta_dot);
    double sum_sq = 0;
    for (size_t i = 0; i < runs[r].run->samples.size(); ++i, row += 3) {
      const MarkSample& s = runs[r].run->samples[i];
      detail::SampleError e;
      // Whitened rows back to metres: L times them (L^-1 = whitening(s)).
      const geometry::Mat3 L = whitening(s).inverse();
      const Eigen::Matrix<double, 3, Eigen::Dynamic> Jp = L * J.middleRows(row, 3);
      e.error_m =
          -L * Vec3(residuals[static_cast<size_t>(row)], residuals[static_cast<size_t>(row + 1)],
                    residuals[static_cast<size_t>(row + 2)]);
      const Eigen::Matrix3d cov = Jp * C * Jp.transpose();
      e.u_reference_m = cov.diagonal().cwiseMax(0.0).cwiseSqrt();
      e.u_stated_m = s.u_w;
      const auto slot = static_cast<size_t>(runs[r].mark_slot[i]);
      e.speed_m_s =
          st.mark[slot][0] * std::abs(theta_dot[static_cast<size_t>(runs[r].time_index[i])]);
      if (options.T_w_camera) {
        const Vec3 q = (s.p_w - e.error_m) - options.T_w_camera->translation();
        const Vec3 axis = options.T_w_camera->linear().col(2);
        e.axis_distance_m = (q - q.dot(axis) * axis).norm();
      }
      e.clockwise = st.clockwise[r];
      sum_sq += e.error_m.squaredNorm();
      errors.push_back(e);
    }
    out.runs[r].rms_residual_m =
        std::sqrt(sum_sq / static_cast<double>(runs[r].run->samples.size()));
  }
  return errors;
}

}  // namespace

PendulumResult identify_pendulum(const std::vector<PendulumRun>& runs,
                                 const PendulumOptions& options) {
  if (runs.empty()) throw EvalInputError("pendulum: no run given");
  std::vector<int> mark_ids;
  const std::vector<detail::PreparedRun> prepared = detail::prepare_runs(runs, mark_ids);
  detail::PendulumState st = detail::initial_state(prepared, mark_ids, options);

  ceres::Problem problem;
  const std::vector<ceres::ResidualBlockId> residual_blocks =
      add_residual_blocks(problem, prepared, st, options);
  ceres::Solver::Options solver;
  solver.linear_solver_type = ceres::DENSE_QR;
  solver.max_num_iterations = 200;
  solver.function_tolerance = 1e-14;
  solver.parameter_tolerance = 1e-12;
  solver.gradient_tolerance = 1e-14;
  solver.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver, &problem, &summary);
  if (!summary.IsSolutionUsable())
    throw EvalInputError("pendulum: the identification failed: " + summary.message);

  const Blocks b = ordered_blocks(st);
  ceres::Problem::EvaluateOptions eval;
  eval.parameter_blocks = b.order;
  eval.residual_blocks = residual_blocks;
  double cost = 0;
  std::vector<double> residuals;
  ceres::CRSMatrix crs;
  problem.Evaluate(eval, &cost, &residuals, nullptr, &crs);
  const Eigen::MatrixXd J = dense(crs);
  const Eigen::MatrixXd normal = J.transpose() * J;
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(normal);
  const double smallest = ldlt.vectorD().minCoeff(), largest = ldlt.vectorD().maxCoeff();
  if (ldlt.info() != Eigen::Success || !(smallest > 1e-14 * largest))
    throw EvalInputError(
        "pendulum: the runs do not determine all parameters (singular normal matrix): add "
        "runs or a longer swing");
  PendulumResult out;
  out.options = options;
  out.residuals = static_cast<int>(residuals.size());
  out.parameters = b.columns;
  out.reduced_chi_square = 2 * cost / std::max(1, out.residuals - out.parameters);
  out.solver_iterations = static_cast<int>(summary.iterations.size());
  for (const PendulumRun& r : runs) {
    out.other_body_samples += r.other_body_samples;
    out.excluded_rows += r.excluded_rows;
  }
  const Eigen::MatrixXd A_inverse =
      ldlt.solve(Eigen::MatrixXd::Identity(normal.rows(), normal.cols()));
  Eigen::MatrixXd C;
  switch (options.covariance_scale) {
    case CovarianceScale::kObserved:
      C = observed_covariance(prepared, J, residuals, A_inverse);
      break;
    case CovarianceScale::kResidual:
      C = out.reduced_chi_square * A_inverse;
      break;
    case CovarianceScale::kStated:
      C = A_inverse;
      break;
  }
  fill_parameters(st, prepared, b, C, options, out);
  detail::summarise_dynamic_errors(sample_errors(st, prepared, residuals, J, C, options, out), out);
  return out;
}

void pendulum_angles(double omega0_sq, double gamma, double theta0,
                     const std::vector<double>& times_s, std::vector<double>& theta,
                     std::vector<double>& theta_dot) {
  detail::integrate_pendulum(omega0_sq, gamma, theta0, times_s, theta, theta_dot);
}

}  // namespace storetrack::eval
