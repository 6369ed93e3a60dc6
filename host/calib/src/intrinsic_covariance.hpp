// Covariance of a converged intrinsic fit: s^2 (J^T W J)^-1, with s^2 = SSR / (2N - p) the
// residual variance (Bjorck, "Numerical Methods for Least Squares Problems", 1996, sec. 1.1;
// what cv::calibrateCamera reports as stdDeviationsIntrinsics).
#pragma once

#include <vector>

#include "intrinsic_refinement.hpp"

namespace storetrack::calib {

struct FitCovariance {
  camera::IntrinsicCovariance intrinsics = camera::IntrinsicCovariance::Zero();  ///< packed
  std::vector<geometry::Mat6> poses;               ///< per view, left perturbation of T_c_b
  Eigen::Matrix2d warp = Eigen::Matrix2d::Zero();  ///< board deflection (c_x, c_y); 0 if not fitted
};

/// The views' poses are eliminated through their 6x6 blocks (Schur complement), so the cost is
/// linear in the number of views. Throws CalibrationError if the normal matrix is singular.
FitCovariance fit_covariance(const std::vector<BoardView>& views,
                             const std::vector<std::vector<char>>& used,
                             const IntrinsicParameterMap& map, const RefinementState& state,
                             double residual_variance);

}  // namespace storetrack::calib
