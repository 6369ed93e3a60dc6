// The free intrinsic parameters z of a fit and their map to the packed 13-vector of
// common/camera: packed = base + M z. Fixed parameters live in `base`; a tied aspect ratio is a
// column of M with two entries (fx = a * fy), so the covariance maps back exactly: M C_z M^T.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "storetrack/calib/intrinsic_calibration.hpp"

namespace storetrack::calib {

class IntrinsicParameterMap {
 public:
  IntrinsicParameterMap(const IntrinsicOptions& options, const camera::Intrinsics& start);

  int size() const { return static_cast<int>(lead_.size()); }
  const Eigen::Matrix<double, camera::kNumIntrinsics, Eigen::Dynamic>& jacobian() const {
    return M_;
  }
  camera::Intrinsics intrinsics(const double* z) const;
  /// weight * d_packed * M into a row-major 2 x size() block, by M's non-zero entries only: per
  /// residual, the dense 2 x 13 x n product cost a general matrix product (a fifth of a small
  /// fit's time). Equal to the dense product bit for bit: M's entries are 1, zeros and one ratio.
  void chain_jacobian(const Eigen::Matrix<double, 2, camera::kNumIntrinsics>& d_packed,
                      double weight, double* d_free) const;
  Eigen::VectorXd free_values(const camera::Intrinsics& in) const;

 private:
  Eigen::Matrix<double, camera::kNumIntrinsics, Eigen::Dynamic> M_;
  camera::IntrinsicVector base_;
  std::vector<int> lead_;  ///< packed index whose value z_j is
  int tied_row_ = -1;      ///< packed index set to tied_ratio_ * z_0 (fx with a fixed aspect)
  double tied_ratio_ = 0;
  int width_, height_;
  camera::LensModel lens_model_;
};

}  // namespace storetrack::calib
