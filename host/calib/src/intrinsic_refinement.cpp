// Analytic Jacobians from common/camera's projection (tested there against central
// differences): no second, templated copy of the camera model is needed for Ceres, and the
// solver needs no automatic differentiation (cheaper to compile and to run).
#include "intrinsic_refinement.hpp"
#include "rig_refinement.hpp"

#include <ceres/ceres.h>

#include <string>
#include <utility>
#include <vector>

namespace storetrack::calib {
namespace {

/// d residual / d pose vector (rotation vector, translation) from the derivative with respect to
/// the pose's left perturbation: the rotation part chains through d(perturbation)/d(rotvec) = J_l
/// (`left_jacobian`, made once per view).
void pose_vector_jacobian(const Eigen::Matrix<double, 2, 6>& d_left,
                          const geometry::Mat3& left_jacobian, double weight, double* out) {
  Eigen::Map<Eigen::Matrix<double, 2, 6, Eigen::RowMajor>> J(out);
  J.leftCols<3>() = weight * d_left.leftCols<3>() * left_jacobian;
  J.rightCols<3>() = weight * d_left.rightCols<3>();
}

geometry::Mat3 rotation_vector_jacobian(const double* pose) {
  return geometry::so3_left_jacobian(Eigen::Map<const geometry::Vec3>(pose));
}

/// Residuals (projected - observed) / sigma of the used points of one board view seen by one
/// camera, two rows per point in `points` order. One block per view, not per point: the camera
/// model, the pose's transform and its rotation Jacobians are made once per view, and Ceres'
/// per-block work is paid once per view (docs/performance.md, issue 28's speed item).
/// Blocks: z; for a camera other than the reference, T_c_r (then T_c_b = T_c_r T_r_b); the
/// board pose (T_c_b, or T_r_b in a rig; each a rotation vector and translation); with a fitted
/// board deflection (`warp` not null), its coefficients (c_x, c_y).
class ViewReprojectionCost final : public ceres::CostFunction {
 public:
  ViewReprojectionCost(std::vector<const Observation*> points, const IntrinsicParameterMap& map,
                       const BoardWarp* warp, bool with_extrinsic)
      : points_(std::move(points)), map_(map), warp_(warp), with_extrinsic_(with_extrinsic) {
    weights_.reserve(points_.size());
    for (const Observation* o : points_)
      weights_.push_back(1.0 / o->weighting_sigma_px());
    set_num_residuals(2 * static_cast<int>(points_.size()));
    mutable_parameter_block_sizes()->push_back(map.size());
    mutable_parameter_block_sizes()->push_back(6);
    if (with_extrinsic_) mutable_parameter_block_sizes()->push_back(6);
    if (warp_) mutable_parameter_block_sizes()->push_back(2);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const ViewGeometry view = view_geometry(parameters, jacobians != nullptr);
    const camera::CameraModel model(map_.intrinsics(parameters[0]));
    const double* warp_c = warp_ ? parameters[warp_block()] : nullptr;
    camera::ProjectionJacobians J;
    for (size_t k = 0; k < points_.size(); ++k) {
      const Observation& obs = *points_[k];
      const geometry::Vec3 p_board = warp_ ? warp_->apply(obs.p_board, warp_c) : obs.p_board;
      const auto pixel = model.project_world(view.T_c_b, p_board, jacobians ? &J : nullptr);
      if (!pixel) return false;  // behind the camera: LM shortens the step
      Eigen::Map<Eigen::Vector2d>(residuals + 2 * k) = weights_[k] * (*pixel - obs.pixel);
      if (jacobians) point_jacobians(view, J, k, jacobians);
    }
    return true;
  }

 private:
  /// What the view's points share: the board-to-camera transform and the chain from its left
  /// perturbation to each pose block's vector.
  struct ViewGeometry {
    geometry::Transform T_c_b;
    geometry::Mat6 d_cb_d_cr, d_cb_d_rb;     ///< with an extrinsic only
    geometry::Mat3 rotvec_cr, rotvec_board;  ///< J_l of T_c_r's and the board pose's rotation
  };

  int board_block() const { return with_extrinsic_ ? 2 : 1; }
  int warp_block() const { return board_block() + 1; }

  ViewGeometry view_geometry(double const* const* parameters, bool with_jacobians) const {
    ViewGeometry g;
    const double* board = parameters[board_block()];
    const geometry::Transform T_board = pose_transform(Eigen::Map<const PoseVector>(board));
    if (!with_extrinsic_) {
      g.T_c_b = T_board;
    } else {
      const geometry::Transform T_c_r = pose_transform(Eigen::Map<const PoseVector>(parameters[1]));
      g.T_c_b = T_c_r * T_board;
      if (with_jacobians) {
        geometry::composition_jacobians(T_c_r, T_board, g.d_cb_d_cr, g.d_cb_d_rb);
        g.rotvec_cr = rotation_vector_jacobian(parameters[1]);
      }
    }
    if (with_jacobians) g.rotvec_board = rotation_vector_jacobian(board);
    return g;
  }

  /// Rows 2k, 2k + 1 of each requested block's (row-major) Jacobian.
  void point_jacobians(const ViewGeometry& g, const camera::ProjectionJacobians& J, size_t k,
                       double** jacobians) const {
    const double w = weights_[k];
    const auto rows = static_cast<ptrdiff_t>(2 * k);
    if (jacobians[0]) map_.chain_jacobian(J.d_intrinsics, w, jacobians[0] + rows * map_.size());
    if (with_extrinsic_ && jacobians[1])
      pose_vector_jacobian(J.d_pose * g.d_cb_d_cr, g.rotvec_cr, w, jacobians[1] + rows * 6);
    if (double* d_board = jacobians[board_block()]) {
      if (with_extrinsic_)
        pose_vector_jacobian(J.d_pose * g.d_cb_d_rb, g.rotvec_board, w, d_board + rows * 6);
      else
        pose_vector_jacobian(J.d_pose, g.rotvec_board, w, d_board + rows * 6);
    }
    if (warp_ && jacobians[warp_block()]) {
      Eigen::Map<Eigen::Matrix<double, 2, 2, Eigen::RowMajor>> Jc(jacobians[warp_block()] +
                                                                  rows * 2);
      Jc = w * J.d_point_world.col(2) * warp_->basis(points_[k]->p_board).transpose();
    }
  }

  std::vector<const Observation*> points_;
  std::vector<double> weights_;
  const IntrinsicParameterMap& map_;
  const BoardWarp* warp_;
  bool with_extrinsic_;
};

/// The used points of one view, in view order (an empty view adds no residual block).
std::vector<const Observation*> used_points(const std::vector<const Observation*>& points,
                                            const std::vector<char>& used) {
  std::vector<const Observation*> out;
  for (size_t k = 0; k < points.size(); ++k)
    if (used[k]) out.push_back(points[k]);
  return out;
}

int solve(ceres::Problem& problem, ceres::ParameterBlockOrdering* ordering) {
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_SCHUR;
  options.linear_solver_ordering.reset(ordering);
  options.max_num_iterations = 200;
  options.function_tolerance = 1e-12;
  options.parameter_tolerance = 1e-12;
  options.gradient_tolerance = 1e-14;
  options.num_threads = 1;
  // Ceres' LM damps with diag(J^T J) of the Jacobian it solves with, so the step does not depend
  // on the columns' scale (Marquardt); the column scaling cost ~5 % of a small fit and moved no
  // result beyond 2e-12 sigma nor any iteration count (docs/performance.md, issue 28).
  options.jacobi_scaling = false;
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
    std::vector<const Observation*> points = used_points(views[i].points, used[i]);
    if (!points.empty())
      problem.AddResidualBlock(new ViewReprojectionCost(std::move(points), map, warp, false),
                               nullptr, blocks);
    if (problem.HasParameterBlock(state.poses[i].data()))
      ordering->AddElementToGroup(state.poses[i].data(), 0);  // eliminated first (Schur)
  }
  // Groups of their own, as in refine_rig: an order that does not move with the heap's layout.
  ordering->AddElementToGroup(state.z.data(), 1);
  if (warp) ordering->AddElementToGroup(state.warp.c.data(), 2);
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
    std::vector<const Observation*> points = used_points(views[i].view.points, used[i]);
    if (!points.empty())
      problem.AddResidualBlock(
          new ViewReprojectionCost(std::move(points), maps[camera], warp, camera > 0), nullptr,
          blocks);
  }
  for (PoseVector& board : state.T_r_b)
    if (problem.HasParameterBlock(board.data()))
      ordering->AddElementToGroup(board.data(), 0);  // eliminated first (Schur)
  // One group per kept block, in camera order: within a group Ceres orders by address, which
  // moves with the heap's layout (then the reduced system's summation order, its last bits).
  int group = 1;
  for (size_t c = 0; c < state.z.size(); ++c) {
    if (problem.HasParameterBlock(state.z[c].data()))
      ordering->AddElementToGroup(state.z[c].data(), group++);
    if (c > 0 && problem.HasParameterBlock(state.T_c_r[c].data()))
      ordering->AddElementToGroup(state.T_c_r[c].data(), group++);
  }
  if (warp) ordering->AddElementToGroup(state.warp.c.data(), group);
  return solve(problem, ordering);
}

}  // namespace storetrack::calib
