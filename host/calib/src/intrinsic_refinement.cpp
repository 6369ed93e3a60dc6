// Analytic Jacobians from common/camera's projection (tested there against central
// differences): no second, templated copy of the camera model is needed for Ceres, and the
// solver needs no automatic differentiation (cheaper to compile and to run).
#include "intrinsic_refinement.hpp"

#include <ceres/ceres.h>

#include <string>

namespace storetrack::calib {
namespace {

/// Residual (projected - observed) / sigma of one board point; blocks: z, pose (rotvec, t).
class ReprojectionCost final : public ceres::CostFunction {
 public:
  ReprojectionCost(const Observation& obs, const IntrinsicParameterMap& map)
      : obs_(obs), map_(map), weight_(1.0 / obs.weighting_sigma_px()) {
    set_num_residuals(2);
    mutable_parameter_block_sizes()->push_back(map.size());
    mutable_parameter_block_sizes()->push_back(6);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const camera::CameraModel model(map_.intrinsics(parameters[0]));
    const Eigen::Map<const PoseVector> pose(parameters[1]);
    const geometry::Transform T_c_b = pose_transform(pose);
    camera::ProjectionJacobians J;
    const auto pixel = model.project_world(T_c_b, obs_.p_board, jacobians ? &J : nullptr);
    if (!pixel) return false;  // behind the camera: LM shortens the step
    Eigen::Map<Eigen::Vector2d> r(residuals);
    r = weight_ * (*pixel - obs_.pixel);
    if (!jacobians) return true;
    if (jacobians[0]) {
      Eigen::Map<Eigen::Matrix<double, 2, Eigen::Dynamic, Eigen::RowMajor>> Jz(jacobians[0], 2,
                                                                               map_.size());
      Jz = weight_ * J.d_intrinsics * map_.jacobian();
    }
    if (jacobians[1]) {
      Eigen::Map<Eigen::Matrix<double, 2, 6, Eigen::RowMajor>> Jp(jacobians[1]);
      // d_pose is over the left perturbation; chain through d(perturbation)/d(rotvec) = J_l.
      Jp.leftCols<3>() =
          weight_ * J.d_pose.leftCols<3>() * geometry::so3_left_jacobian(pose.head<3>());
      Jp.rightCols<3>() = weight_ * J.d_pose.rightCols<3>();
    }
    return true;
  }

 private:
  const Observation& obs_;
  const IntrinsicParameterMap& map_;
  double weight_;
};

}  // namespace

int refine_intrinsics(const std::vector<BoardView>& views,
                      const std::vector<std::vector<char>>& used, const IntrinsicParameterMap& map,
                      RefinementState& state) {
  ceres::Problem::Options problem_options;
  ceres::Problem problem(problem_options);
  auto* ordering = new ceres::ParameterBlockOrdering;  // owned by the solver options
  for (size_t i = 0; i < views.size(); ++i) {
    for (size_t k = 0; k < views[i].points.size(); ++k)
      if (used[i][k])
        problem.AddResidualBlock(new ReprojectionCost(*views[i].points[k], map), nullptr,
                                 state.z.data(), state.poses[i].data());
    if (problem.HasParameterBlock(state.poses[i].data()))
      ordering->AddElementToGroup(state.poses[i].data(), 0);  // eliminated first (Schur)
  }
  ordering->AddElementToGroup(state.z.data(), 1);

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
    throw CalibrationError("Levenberg-Marquardt failed: " + summary.message);
  return static_cast<int>(summary.iterations.size());
}

}  // namespace storetrack::calib
