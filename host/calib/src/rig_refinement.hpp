// The rig's joint Levenberg-Marquardt (in intrinsic_refinement.cpp, the one Ceres translation
// unit) and its covariance (rig_covariance.cpp).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "board_views.hpp"
#include "intrinsic_refinement.hpp"

namespace storetrack::calib {

/// One camera's view of one board pose.
struct RigView {
  int camera = 0;  ///< index into the rig's cameras (0 = reference)
  int board = 0;   ///< index into the board poses
  BoardView view;
};

struct RigState {
  std::vector<Eigen::VectorXd> z;  ///< per camera: free intrinsics (its IntrinsicParameterMap)
  std::vector<PoseVector> T_c_r;   ///< per camera; [0] is the identity and stays fixed
  std::vector<PoseVector> T_r_b;   ///< per board pose
  BoardWarp warp;                  ///< the board's deflection, shared by every camera and pose
};

/// T_c_b of a rig view at the current state.
inline geometry::Transform rig_view_transform(const RigState& state, const RigView& v) {
  return pose_transform(state.T_c_r[static_cast<size_t>(v.camera)]) *
         pose_transform(state.T_r_b[static_cast<size_t>(v.board)]);
}

/// used[i][k]: point k of view i takes part. Returns the LM iterations; throws CalibrationError.
int refine_rig(const std::vector<RigView>& views, const std::vector<std::vector<char>>& used,
               const std::vector<IntrinsicParameterMap>& maps, RigState& state);

struct RigCovariance {
  Eigen::MatrixXd joint;                           ///< layout of RigResult::joint_covariance
  Eigen::Matrix2d warp = Eigen::Matrix2d::Zero();  ///< board deflection; 0 if not fitted
};

/// s^2 (J^T W J)^-1 over every camera's packed intrinsics and extrinsics and the board
/// deflection, the board poses eliminated by their 6x6 blocks (Schur complement: exactly the
/// marginal of the full inverse). frames[f]: board pose f's frame (for messages). Throws
/// CalibrationError if singular.
RigCovariance rig_covariance(const std::vector<RigView>& views,
                             const std::vector<std::vector<char>>& used,
                             const std::vector<IntrinsicParameterMap>& maps, const RigState& state,
                             const std::vector<int>& frames, double residual_variance);

}  // namespace storetrack::calib
