// Levenberg-Marquardt of the free intrinsics and every view's pose (Ceres; the only translation
// unit that includes Ceres, to keep the build quick).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "board_views.hpp"
#include "board_warp.hpp"
#include "intrinsic_parameters.hpp"
#include "storetrack/geometry/transform.hpp"

namespace storetrack::calib {

/// Pose of view i as (rotation vector of R_c_b [rad], t_c_b [m]).
using PoseVector = Eigen::Matrix<double, 6, 1>;

/// T_c_b of a view's pose vector (the one place that reads its layout).
inline geometry::Transform pose_transform(const PoseVector& pose) {
  return geometry::make_transform(pose.head<3>(), pose.tail<3>());
}

struct RefinementState {
  Eigen::VectorXd z;              ///< free intrinsics (IntrinsicParameterMap)
  std::vector<PoseVector> poses;  ///< one per view
  BoardWarp warp;                 ///< the board's deflection; its c estimated when warp.fitted
};

/// used[i][k]: point k of view i takes part (outlier rejection clears it). Returns the number
/// of LM iterations; throws CalibrationError if the solver fails.
int refine_intrinsics(const std::vector<BoardView>& views,
                      const std::vector<std::vector<char>>& used, const IntrinsicParameterMap& map,
                      RefinementState& state);

}  // namespace storetrack::calib
