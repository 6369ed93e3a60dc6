// Analytic Jacobians from common/camera's projection (tested there against central
// differences): no second, templated copy of the camera model is needed for Ceres, and the
// solver needs no automatic differentiation (cheaper to compile and to run).
#include "intrinsic_refinement.hpp"
#include "rig_refinement.hpp"

#include <ceres/ceres.h>

#include <string>
#include <vector>

namespace storetrack::calib {
namespace {

/// d residual / d pose vector (rotation vector, translation) from the derivative with respect to
/// the pose's left perturbation: the rotation part chains through d(perturbation)/d(rotvec) = J_l.
void pose_vector_jacobian(const Eigen::Matrix<double, 2, 6>& d_left, const double* pose,
                          double weight, double* out) {
  Eigen::Map<Eigen::Matrix<double, 2, 6, Eigen::RowMajor>> J(out);
  J.leftCols<3>() = weight * d_left.leftCols<3>() *
                    geometry::so3_left_jacobian(Eigen::Map<const geometry::Vec3>(pose));
  J.rightCols<3>() = weight * d_left.rightCols<3>();
}

/// Residual (projected - observed) / sigma of one board point; blocks: z, pose (rotvec, t) and,
/// with a fitted board deflection (`warp` not null), its coefficients (c_x, c_y).
class ReprojectionCost final : public ceres::CostFunction {
 public:
  ReprojectionCost(const Observation& obs, const IntrinsicParameterMap& map,
                   const BoardWarp* warp = nullptr)
      : obs_(obs), map_(map), warp_(warp), weight_(1.0 / obs.weighting_sigma_px()) {
    set_num_residuals(2);
    mutable_parameter_block_sizes()->push_back(map.size());
    mutable_parameter_block_sizes()->push_back(6);
    if (warp_) mutable_parameter_block_sizes()->push_back(2);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const camera::CameraModel model(map_.intrinsics(parameters[0]));
    const Eigen::Map<const PoseVector> pose(parameters[1]);
    const geometry::Transform T_c_b = pose_transform(pose);
    const geometry::Vec3 p_board = warp_ ? warp_->apply(obs_.p_board, parameters[2]) : obs_.p_board;
    camera::ProjectionJacobians J;
    const auto pixel = model.project_world(T_c_b, p_board, jacobians ? &J : nullptr);
    if (!pixel) return false;  // behind the camera: LM shortens the step
    Eigen::Map<Eigen::Vector2d> r(residuals);
    r = weight_ * (*pixel - obs_.pixel);
    if (!jacobians) return true;
    if (jacobians[0]) map_.chain_jacobian(J.d_intrinsics, weight_, jacobians[0]);
    if (jacobians[1]) pose_vector_jacobian(J.d_pose, parameters[1], weight_, jacobians[1]);
    if (warp_ && jacobians[2]) {
      Eigen::Map<Eigen::Matrix<double, 2, 2, Eigen::RowMajor>> Jc(jacobians[2]);
      Jc = weight_ * J.d_point_world.col(2) * warp_->basis(obs_.p_board).transpose();
    }
    return true;
  }

 private:
  const Observation& obs_;
  const IntrinsicParameterMap& map_;
  const BoardWarp* warp_;
  double weight_;
};

/// The same residual for a camera other than the reference: T_c_b = T_c_r T_r_b; blocks z,
/// T_c_r, T_r_b (each pose a rotation vector and translation) and, with a fitted board
/// deflection, its (c_x, c_y). The reference camera's points use ReprojectionCost with T_r_b as
/// the pose (T_c_r = identity).
class RigReprojectionCost final : public ceres::CostFunction {
 public:
  RigReprojectionCost(const Observation& obs, const IntrinsicParameterMap& map,
                      const BoardWarp* warp)
      : obs_(obs), map_(map), warp_(warp), weight_(1.0 / obs.weighting_sigma_px()) {
    set_num_residuals(2);
    mutable_parameter_block_sizes()->push_back(map.size());
    mutable_parameter_block_sizes()->push_back(6);
    mutable_parameter_block_sizes()->push_back(6);
    if (warp_) mutable_parameter_block_sizes()->push_back(2);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const camera::CameraModel model(map_.intrinsics(parameters[0]));
    const geometry::Transform T_c_r = pose_transform(Eigen::Map<const PoseVector>(parameters[1]));
    const geometry::Transform T_r_b = pose_transform(Eigen::Map<const PoseVector>(parameters[2]));
    camera::ProjectionJacobians J;
    const geometry::Vec3 p_board = warp_ ? warp_->apply(obs_.p_board, parameters[3]) : obs_.p_board;
    const auto pixel = model.project_world(T_c_r * T_r_b, p_board, jacobians ? &J : nullptr);
    if (!pixel) return false;
    Eigen::Map<Eigen::Vector2d> r(residuals);
    r = weight_ * (*pixel - obs_.pixel);
    if (!jacobians) return true;
    if (jacobians[0]) map_.chain_jacobian(J.d_intrinsics, weight_, jacobians[0]);
    geometry::Mat6 d_cb_d_cr, d_cb_d_rb;
    geometry::composition_jacobians(T_c_r, T_r_b, d_cb_d_cr, d_cb_d_rb);
    if (jacobians[1])
      pose_vector_jacobian(J.d_pose * d_cb_d_cr, parameters[1], weight_, jacobians[1]);
    if (jacobians[2])
      pose_vector_jacobian(J.d_pose * d_cb_d_rb, parameters[2], weight_, jacobians[2]);
    if (warp_ && jacobians[3]) {
      Eigen::Map<Eigen::Matrix<double, 2, 2, Eigen::RowMajor>> Jc(jacobians[3]);
      Jc = weight_ * J.d_point_world.col(2) * warp_->basis(obs_.p_board).transpose();
    }
    return true;
  }

 private:
  const Observation& obs_;
  const IntrinsicParameterMap& map_;
  const BoardWarp* warp_;
  double weight_;
};

int solve(ceres::Problem& problem, ceres::ParameterBlockOrdering* ordering) {
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_SCHUR;
  options.linear_solver_ordering.reset(ordering);
  options.max_num_iterations = 200;
  options.function_tolerance = 1e-12;
  options.parameter_tolerance = 1e-12;
  options.gradient_tolerance = 1e-14;
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  if (!summary.IsSolutionUsable())
    // Ceres's message names parameter blocks by address: ours names the status only (the caller
    // names the camera); degenerate views are screened out before (view_screening.hpp).
    throw CalibrationError(
        std::string("the least-squares fit (Levenberg-Marquardt) found no usable solution (") +
        ceres::TerminationTypeToString(summary.termination_type) +
        "): a parameter or residual is not finite from this start");
  return static_cast<int>(summary.iterations.size());
}

}  // namespace

int refine_intrinsics(const std::vector<BoardView>& views,
                      const std::vector<std::vector<char>>& used, const IntrinsicParameterMap& map,
                      RefinementState& state) {
  ceres::Problem::Options problem_options;
  ceres::Problem problem(problem_options);
  auto* ordering = new ceres::ParameterBlockOrdering;  // owned by the solver options
  const BoardWarp* warp = state.warp.fitted ? &state.warp : nullptr;
  std::vector<double*> blocks = {state.z.data(), nullptr};
  if (warp) blocks.push_back(state.warp.c.data());
  for (size_t i = 0; i < views.size(); ++i) {
    blocks[1] = state.poses[i].data();
    for (size_t k = 0; k < views[i].points.size(); ++k)
      if (used[i][k])
        problem.AddResidualBlock(new ReprojectionCost(*views[i].points[k], map, warp), nullptr,
                                 blocks);
    if (problem.HasParameterBlock(state.poses[i].data()))
      ordering->AddElementToGroup(state.poses[i].data(), 0);  // eliminated first (Schur)
  }
  ordering->AddElementToGroup(state.z.data(), 1);
  if (warp) ordering->AddElementToGroup(state.warp.c.data(), 1);
  return solve(problem, ordering);
}

int refine_rig(const std::vector<RigView>& views, const std::vector<std::vector<char>>& used,
               const std::vector<IntrinsicParameterMap>& maps, RigState& state) {
  ceres::Problem problem;
  auto* ordering = new ceres::ParameterBlockOrdering;  // owned by the solver options
  const BoardWarp* warp = state.warp.fitted ? &state.warp : nullptr;
  for (size_t i = 0; i < views.size(); ++i) {
    const auto camera = static_cast<size_t>(views[i].camera);
    double* board = state.T_r_b[static_cast<size_t>(views[i].board)].data();
    std::vector<double*> blocks = {state.z[camera].data()};
    if (camera > 0) blocks.push_back(state.T_c_r[camera].data());
    blocks.push_back(board);
    if (warp) blocks.push_back(state.warp.c.data());
    for (size_t k = 0; k < views[i].view.points.size(); ++k) {
      if (!used[i][k]) continue;
      const Observation& o = *views[i].view.points[k];
      if (camera == 0)
        problem.AddResidualBlock(new ReprojectionCost(o, maps[0], warp), nullptr, blocks);
      else
        problem.AddResidualBlock(new RigReprojectionCost(o, maps[camera], warp), nullptr, blocks);
    }
  }
  if (warp) ordering->AddElementToGroup(state.warp.c.data(), 1);
  for (PoseVector& board : state.T_r_b)
    if (problem.HasParameterBlock(board.data()))
      ordering->AddElementToGroup(board.data(), 0);  // eliminated first (Schur)
  for (size_t c = 0; c < state.z.size(); ++c) {
    if (problem.HasParameterBlock(state.z[c].data()))
      ordering->AddElementToGroup(state.z[c].data(), 1);
    if (c > 0 && problem.HasParameterBlock(state.T_c_r[c].data()))
      ordering->AddElementToGroup(state.T_c_r[c].data(), 1);
  }
  return solve(problem, ordering);
}

}  // namespace storetrack::calib
