#include "storetrack/uncertainty/calibration_factors.hpp"

#include <cmath>
#include <stdexcept>

#include "storetrack/geometry/symmetric_eigen.hpp"

namespace storetrack::uncertainty {
namespace {

// Square-root factor F (n x r) with F F^T = cov, dropping null directions.
Eigen::MatrixXd sqrt_factor(const Eigen::MatrixXd& cov, double relative_floor) {
  if (!cov.allFinite()) throw std::invalid_argument("calibration covariance is not finite");
  const Eigen::MatrixXd sym = 0.5 * (cov + cov.transpose());
  const geometry::SymmetricEigen eig = geometry::symmetric_eigen(sym);
  const Eigen::VectorXd& lambda = eig.values;
  const double largest = lambda.size() > 0 ? lambda.maxCoeff() : 0.0;
  if (largest <= 0) return Eigen::MatrixXd(cov.rows(), 0);
  if (lambda.minCoeff() < -1e-9 * largest)
    throw std::invalid_argument("calibration covariance is not positive semi-definite");
  std::vector<int> kept;
  for (int i = 0; i < lambda.size(); ++i)
    if (lambda(i) > relative_floor * largest) kept.push_back(i);
  Eigen::MatrixXd F(cov.rows(), static_cast<int>(kept.size()));
  for (size_t j = 0; j < kept.size(); ++j)
    F.col(static_cast<int>(j)) = eig.vectors.col(kept[j]) * std::sqrt(lambda(kept[j]));
  return F;
}

}  // namespace

CalibrationFactors::CalibrationFactors(const camera::RigCalibration& rig, double relative_floor) {
  cameras_.resize(rig.cameras.size());
  std::vector<Eigen::MatrixXd> intr(rig.cameras.size()), extr(rig.cameras.size());
  int col = 0;
  ranges_[index(Source::kIntrinsic)].first = col;
  for (size_t c = 0; c < rig.cameras.size(); ++c) {
    intr[c] = sqrt_factor(rig.cameras[c].intrinsic_covariance, relative_floor);
    cameras_[c].intrinsic_begin = col;
    cameras_[c].intrinsic = intr[c];
    col += static_cast<int>(intr[c].cols());
  }
  ranges_[index(Source::kIntrinsic)].second = col - ranges_[index(Source::kIntrinsic)].first;
  ranges_[index(Source::kExtrinsic)].first = col;
  for (size_t c = 0; c < rig.cameras.size(); ++c) {
    extr[c] = sqrt_factor(rig.cameras[c].extrinsic_covariance, relative_floor);
    cameras_[c].extrinsic_begin = col;
    cameras_[c].extrinsic = extr[c];
    col += static_cast<int>(extr[c].cols());
  }
  ranges_[index(Source::kExtrinsic)].second = col - ranges_[index(Source::kExtrinsic)].first;
  ranges_[index(Source::kSync)].first = col;
  for (size_t c = 0; c < rig.cameras.size(); ++c) {
    const double sigma_ns = rig.cameras[c].exposure_offset_sigma_ns;
    if (!(sigma_ns >= 0) || !std::isfinite(sigma_ns))
      throw std::invalid_argument("exposure_offset_sigma_ns must be finite and >= 0");
    if (sigma_ns > 0) {
      cameras_[c].sync_column = col++;
      cameras_[c].sync_sigma_s = sigma_ns * 1e-9;
    }
  }
  ranges_[index(Source::kSync)].second = col - ranges_[index(Source::kSync)].first;
  ranges_[index(Source::kCentroid)] = {col, 0};
  ranges_[index(Source::kSurvey)] = {col, 0};
  ranges_[index(Source::kProcess)] = {col, 0};  // not a calibration factor
  num_factors_ = col;
}

}  // namespace storetrack::uncertainty
