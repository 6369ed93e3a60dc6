#include "intrinsic_parameters.hpp"

namespace storetrack::calib {
namespace {
// Packed indices (common/camera/camera_model.hpp).
enum Packed : int { kFx, kFy, kCx, kCy, kSkew, kK1, kK2, kP1, kP2, kK3, kK4, kK5, kK6 };

/// The free Brown coefficients, as cv::calibrateCamera's flags choose them.
void add_rational_brown(const IntrinsicOptions& o, std::vector<int>& free) {
  if (!o.fix_k1) free.push_back(kK1);
  if (!o.fix_k2) free.push_back(kK2);
  if (!o.zero_tangential) {
    free.push_back(kP1);
    free.push_back(kP2);
  }
  if (!o.fix_k3) free.push_back(kK3);
  if (o.rational)
    for (int k : {kK4, kK5, kK6})
      free.push_back(k);
}

}  // namespace

IntrinsicParameterMap::IntrinsicParameterMap(const IntrinsicOptions& o,
                                             const camera::Intrinsics& start)
    : base_(camera::pack(start)),
      width_(start.width),
      height_(start.height),
      lens_model_(start.lens_model) {
  std::vector<int> free;
  if (!o.fix_aspect_ratio) free.push_back(kFx);
  free.push_back(kFy);
  if (!o.fix_principal_point) {
    free.push_back(kCx);
    free.push_back(kCy);
  }
  // skew: the model has it, cv::calibrateCamera does not estimate it; fixed at its start (0).
  if (start.lens_model == camera::LensModel::kKannalaBrandt) {
    // k1..k4 occupy packed entries 5..8 (camera_model.hpp); 9..12 are unused.
    for (int k = kK1; k < kK1 + camera::lens_coefficient_count(start.lens_model); ++k)
      free.push_back(k);
  } else {
    add_rational_brown(o, free);
  }
  lead_ = free;
  M_.setZero(camera::kNumIntrinsics, static_cast<Eigen::Index>(free.size()));
  for (size_t j = 0; j < free.size(); ++j) {
    M_(free[j], static_cast<Eigen::Index>(j)) = 1;
    base_[free[j]] = 0;
  }
  if (o.fix_aspect_ratio) {
    M_(kFx, 0) = o.aspect_ratio;  // column 0 is fy
    base_[kFx] = 0;
    tied_row_ = kFx;
    tied_ratio_ = o.aspect_ratio;
  }
}

// Both below walk M's non-zero entries: its column j is 1 at lead_[j], and column 0 also holds
// tied_ratio_ at tied_row_; the free rows of base_ are 0.
camera::Intrinsics IntrinsicParameterMap::intrinsics(const double* z) const {
  camera::IntrinsicVector packed = base_;
  for (int j = 0; j < size(); ++j)
    packed[lead_[static_cast<size_t>(j)]] += z[j];
  if (tied_row_ >= 0) packed[tied_row_] += tied_ratio_ * z[0];
  return camera::unpack(packed, width_, height_, lens_model_);
}

void IntrinsicParameterMap::chain_jacobian(
    const Eigen::Matrix<double, 2, camera::kNumIntrinsics>& d_packed, double weight,
    double* d_free) const {
  Eigen::Map<Eigen::Matrix<double, 2, Eigen::Dynamic, Eigen::RowMajor>> out(d_free, 2, size());
  for (int j = 0; j < size(); ++j)
    out.col(j) = d_packed.col(lead_[static_cast<size_t>(j)]);
  if (tied_row_ >= 0) out.col(0) += tied_ratio_ * d_packed.col(tied_row_);
  out *= weight;  // last, as the dense product applies its scalar factor
}

Eigen::VectorXd IntrinsicParameterMap::free_values(const camera::Intrinsics& in) const {
  const camera::IntrinsicVector packed = camera::pack(in);
  Eigen::VectorXd z(size());
  for (int j = 0; j < size(); ++j)
    z[j] = packed[lead_[static_cast<size_t>(j)]];
  return z;
}

}  // namespace storetrack::calib
