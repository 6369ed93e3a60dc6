#include "storetrack/uncertainty/calibration_factors.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <type_traits>

#include "storetrack/geometry/symmetric_eigen.hpp"

namespace storetrack::uncertainty {
namespace {

// f(std::integral_constant<int, N>{}) for N = n in [Min, Max]; nothing for any other n. Turns a
// run-time count of parameters into a fixed size: for so few columns a run-time sized product
// costs more than the arithmetic it skips. Each size is a copy of f's code: here, in one
// translation unit, and no more sizes than can occur.
template <int Min, int Max, typename F>
void with_fixed_size(int n, F&& f) {
  if constexpr (Max >= Min) {
    if (n == Max)
      f(std::integral_constant<int, Max>{});
    else
      with_fixed_size<Min, Max - 1>(n, f);
  }
}

// Square-root factor F (n x r) with F F^T = cov, dropping null directions, and the map
// to_factors (n x r) with z = to_factors^T theta on F's range. The eigen-decomposition is of the
// correlation matrix: parameters of very different scales (px^2 next to 1e-10) keep their
// relative accuracy, and the floor is relative in those units. Fixed parameters (zero
// variance) get zero rows.
struct SqrtFactor {
  Eigen::MatrixXd F, to_factors;
};

SqrtFactor sqrt_factor_with_inverse(const Eigen::MatrixXd& cov, double relative_floor) {
  if (!cov.allFinite()) throw std::invalid_argument("calibration covariance is not finite");
  const Eigen::Index n = cov.rows();
  Eigen::VectorXd sd(n), inv_sd(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    if (cov(i, i) < 0)
      throw std::invalid_argument("calibration covariance is not positive semi-definite");
    sd(i) = std::sqrt(cov(i, i));
    inv_sd(i) = sd(i) > 0 ? 1 / sd(i) : 0.0;
  }
  const Eigen::MatrixXd corr =
      inv_sd.asDiagonal() * (0.5 * (cov + cov.transpose())) * inv_sd.asDiagonal();
  const geometry::SymmetricEigen eig = geometry::symmetric_eigen(corr);
  const Eigen::VectorXd& lambda = eig.values;
  const double largest = lambda.size() > 0 ? lambda.maxCoeff() : 0.0;
  SqrtFactor out{Eigen::MatrixXd(n, 0), Eigen::MatrixXd(n, 0)};
  if (largest <= 0) return out;
  if (lambda.minCoeff() < -1e-9 * largest)
    throw std::invalid_argument("calibration covariance is not positive semi-definite");
  std::vector<int> kept;
  for (int i = 0; i < lambda.size(); ++i)
    if (lambda(i) > relative_floor * largest) kept.push_back(i);
  out.F.resize(n, static_cast<int>(kept.size()));
  out.to_factors.resize(n, static_cast<int>(kept.size()));
  for (size_t j = 0; j < kept.size(); ++j) {
    const auto col = static_cast<Eigen::Index>(j);
    const double root = std::sqrt(lambda(kept[j]));
    out.F.col(col) = sd.cwiseProduct(eig.vectors.col(kept[j])) * root;
    out.to_factors.col(col) = inv_sd.cwiseProduct(eig.vectors.col(kept[j])) / root;
  }
  return out;
}

Eigen::MatrixXd sqrt_factor(const Eigen::MatrixXd& cov, double relative_floor) {
  return sqrt_factor_with_inverse(cov, relative_floor).F;
}

}  // namespace

CalibrationFactors::CalibrationFactors(const camera::RigCalibration& rig, double relative_floor) {
  cameras_.resize(rig.cameras.size());
  if (rig.has_cross_covariance())
    factor_jointly(rig, relative_floor);
  else
    factor_per_camera(rig, relative_floor);
  add_sync_factors(rig);
  compute_camera_covariances();
  find_estimated_parameters();
}

void CalibrationFactors::find_estimated_parameters() {
  estimated_covariances_.assign(cameras_.size(), {});
  for (size_t c = 0; c < cameras_.size(); ++c) {
    CameraFactors& cf = cameras_[c];
    cf.num_estimated_intrinsics = 0;
    cf.estimated_intrinsic_rows.setZero(camera::kNumIntrinsics, cf.intrinsic.cols());
    if (cf.intrinsic.cols() > 0)
      for (int k = 0; k < camera::kNumIntrinsics; ++k) {
        if (cf.intrinsic.row(k).isZero(0.0)) continue;
        cf.estimated_intrinsic_rows.row(cf.num_estimated_intrinsics) = cf.intrinsic.row(k);
        cf.estimated_intrinsics[static_cast<size_t>(cf.num_estimated_intrinsics++)] = k;
      }
    // A zero factor row is a zero row and column of F_c F_c^T.
    EstimatedCovariance& e = estimated_covariances_[c];
    e.count = 0;
    for (int k = 0; k < cf.num_estimated_intrinsics; ++k)
      e.parameters[static_cast<size_t>(e.count++)] =
          cf.estimated_intrinsics[static_cast<size_t>(k)];
    for (int k = 0; k < 6; ++k)
      e.parameters[static_cast<size_t>(e.count++)] = camera::kNumIntrinsics + k;
    e.covariance.resize(e.count, e.count);
    for (int a = 0; a < e.count; ++a)
      for (int b = 0; b < e.count; ++b)
        e.covariance(a, b) = camera_covariances_[c](e.parameters[static_cast<size_t>(a)],
                                                    e.parameters[static_cast<size_t>(b)]);
    e.intrinsics_uncorrelated_with_pose =
        e.covariance.topRightCorner(cf.num_estimated_intrinsics, 6).isZero(0.0);
  }
}

void CalibrationFactors::compute_camera_covariances() {
  constexpr int kI = camera::kNumIntrinsics;
  camera_covariances_.assign(cameras_.size(), CameraCovariance::Zero());
  for (size_t c = 0; c < cameras_.size(); ++c) {
    const CameraFactors& cf = cameras_[c];
    // The camera's parameter rows over all factor columns: P P^T = F_c F_c^T.
    Eigen::MatrixXd P = Eigen::MatrixXd::Zero(camera::kJointBlockSize, num_factors_);
    if (cf.intrinsic.cols() > 0)
      P.block(0, cf.intrinsic_begin, kI, cf.intrinsic.cols()) = cf.intrinsic;
    if (cf.extrinsic.cols() > 0)
      P.block(kI, cf.extrinsic_begin, 6, cf.extrinsic.cols()) = cf.extrinsic;
    camera_covariances_[c] = P * P.transpose();
  }
}

void CalibrationFactors::factor_per_camera(const camera::RigCalibration& rig,
                                           double relative_floor) {
  int col = 0;
  ranges_[index(Source::kIntrinsic)].first = col;
  for (size_t c = 0; c < rig.cameras.size(); ++c) {
    cameras_[c].intrinsic = sqrt_factor(rig.cameras[c].intrinsic_covariance, relative_floor);
    cameras_[c].intrinsic_begin = col;
    col += static_cast<int>(cameras_[c].intrinsic.cols());
  }
  ranges_[index(Source::kIntrinsic)].second = col - ranges_[index(Source::kIntrinsic)].first;
  ranges_[index(Source::kExtrinsic)].first = col;
  for (size_t c = 0; c < rig.cameras.size(); ++c) {
    cameras_[c].extrinsic = sqrt_factor(rig.cameras[c].extrinsic_covariance, relative_floor);
    cameras_[c].extrinsic_begin = col;
    col += static_cast<int>(cameras_[c].extrinsic.cols());
  }
  ranges_[index(Source::kExtrinsic)].second = col - ranges_[index(Source::kExtrinsic)].first;
  num_factors_ = col;
}

// Intrinsics of all cameras first (F_I), then the extrinsics given them: the regression
// A = Sigma_EI F_I^+T (F_I^+ = to_factors^T on F_I's range) and the factor of the remainder
// Sigma_EE - A A^T. Cov(theta_E, theta_I) = A F_I^T =
// Sigma_EI (Sigma_EI lies in Sigma_II's range for a PSD joint). The budget's intrinsic source
// thereby includes the part of the extrinsic error explained by the intrinsic one.
void CalibrationFactors::factor_jointly(const camera::RigCalibration& rig, double relative_floor) {
  coupled_ = true;
  constexpr int kI = camera::kNumIntrinsics;
  const int n = static_cast<int>(rig.cameras.size());
  const Eigen::MatrixXd& joint = rig.joint_covariance;
  Eigen::MatrixXd S_II(kI * n, kI * n), S_EE(6 * n, 6 * n), S_EI(6 * n, kI * n);
  for (int a = 0; a < n; ++a)
    for (int b = 0; b < n; ++b) {
      const int ja = camera::kJointBlockSize * a, jb = camera::kJointBlockSize * b;
      S_II.block<kI, kI>(kI * a, kI * b) = joint.block<kI, kI>(ja, jb);
      S_EE.block<6, 6>(6 * a, 6 * b) = joint.block<6, 6>(ja + kI, jb + kI);
      S_EI.block<6, kI>(6 * a, kI * b) = joint.block<6, kI>(ja + kI, jb);
    }
  const SqrtFactor intrinsic = sqrt_factor_with_inverse(S_II, relative_floor);
  const Eigen::MatrixXd& F_I = intrinsic.F;
  const Eigen::MatrixXd A = S_EI * intrinsic.to_factors;
  const Eigen::MatrixXd remainder = S_EE - A * A.transpose();
  const Eigen::MatrixXd F_E = sqrt_factor(remainder, relative_floor);
  const int r_I = static_cast<int>(F_I.cols()), r_E = static_cast<int>(F_E.cols());
  const bool extrinsic_loads_intrinsic = !A.isZero(0.0);
  // Rows of a factor that may have no columns (a zero covariance has rank 0): Eigen's block of
  // an empty matrix offsets its null data pointer, which UBSan reports.
  const auto rows = [](const Eigen::MatrixXd& M, int begin, int count) -> Eigen::MatrixXd {
    if (M.cols() == 0) return Eigen::MatrixXd(count, 0);
    return M.middleRows(begin, count);
  };
  for (int c = 0; c < n; ++c) {
    CameraFactors& cf = cameras_[static_cast<size_t>(c)];
    cf.intrinsic_begin = 0;
    cf.intrinsic = rows(F_I, kI * c, kI);
    if (extrinsic_loads_intrinsic) {
      cf.extrinsic_begin = 0;
      cf.extrinsic.resize(6, r_I + r_E);
      cf.extrinsic << rows(A, 6 * c, 6), rows(F_E, 6 * c, 6);
    } else {
      cf.extrinsic_begin = r_I;
      cf.extrinsic = rows(F_E, 6 * c, 6);
    }
  }
  ranges_[index(Source::kIntrinsic)] = {0, r_I};
  ranges_[index(Source::kExtrinsic)] = {r_I, r_E};
  num_factors_ = r_I + r_E;
}

void CalibrationFactors::add_sync_factors(const camera::RigCalibration& rig) {
  int col = num_factors_;
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
  std::vector<std::pair<int, int>> unit_columns;  // (unit id, column), in camera order
  for (size_t c = 0; c < rig.cameras.size(); ++c) {
    const int unit = rig.cameras[c].unit_id;
    auto it = std::find_if(unit_columns.begin(), unit_columns.end(),
                           [unit](const std::pair<int, int>& u) { return u.first == unit; });
    if (it == unit_columns.end()) it = unit_columns.insert(it, {unit, col++});
    cameras_[c].clock_column = it->second;
  }
  ranges_[index(Source::kSync)].second = col - ranges_[index(Source::kSync)].first;
  ranges_[index(Source::kCentroid)] = {col, 0};
  ranges_[index(Source::kSurvey)] = {col, 0};
  ranges_[index(Source::kProcess)] = {col, 0};  // not a calibration factor
  num_factors_ = col;
}

namespace {

// Adds B B^T to `cov` when the camera owns B's columns (uncoupled factors; cov not null). One
// pass over B's few columns with the six sums in registers: six dynamic-length dot products of
// 6 to 13 elements cost more in set-up than in arithmetic.
template <typename Block>
void add_block_covariance(const Block& B, Eigen::Matrix3d* cov) {
  if (cov == nullptr) return;
  const double* r0 = B.row(0).data();
  const double* r1 = B.row(1).data();
  const double* r2 = B.row(2).data();
  double s00 = 0, s01 = 0, s02 = 0, s11 = 0, s12 = 0, s22 = 0;
  for (Eigen::Index j = 0; j < B.cols(); ++j) {
    s00 += r0[j] * r0[j];
    s01 += r0[j] * r1[j];
    s02 += r0[j] * r2[j];
    s11 += r1[j] * r1[j];
    s12 += r1[j] * r2[j];
    s22 += r2[j] * r2[j];
  }
  Eigen::Matrix3d& C = *cov;
  C(0, 0) += s00;
  C(1, 1) += s11;
  C(2, 2) += s22;
  C(0, 1) += s01;
  C(1, 0) += s01;
  C(0, 2) += s02;
  C(2, 0) += s02;
  C(1, 2) += s12;
  C(2, 1) += s12;
}

// B += A F over the columns [begin, begin + F.cols()) of the loadings (A: K columns, fixed;
// F's first K rows), and cov += B B^T (cov not null). A camera's own factor of full rank over
// its K parameters (uncoupled factors) is K x K: the product is then fixed-size too.
template <int K, typename MatA, typename Factor>
void add_camera_block(const MatA& A, const Factor& F, Eigen::Index begin, Loadings3& loadings,
                      Eigen::Matrix3d* cov) {
  if (F.cols() == K) {
    auto B = loadings.middleCols<K>(begin);
    add_loadings_product(A, F.template topLeftCorner<K, K>(), B);
    add_block_covariance(B, cov);
  } else {
    auto B = loadings.middleCols(begin, F.cols());
    add_loadings_product(A, F, B);
    add_block_covariance(B, cov);
  }
}

}  // namespace

Eigen::Matrix2d pixel_covariance(const CalibrationFactors& f, int slot,
                                 const camera::ProjectionJacobians& J) {
  // Over the parameters with a non-zero covariance only (the fixed intrinsics' rows and columns
  // are exactly zero: skipping them leaves every sum as it was), fixed-size: the 6 pose
  // parameters and 0 to all of the intrinsics.
  const CalibrationFactors::EstimatedCovariance& e = f.estimated_covariance(slot);
  Eigen::Matrix2d S = Eigen::Matrix2d::Zero();
  with_fixed_size<6, camera::kJointBlockSize>(e.count, [&](auto size) {
    constexpr int N = decltype(size)::value;
    Eigen::Matrix<double, 2, N> Jc;
    for (int k = 0; k < N; ++k) {
      const int p = e.parameters[static_cast<size_t>(k)];
      if (p < camera::kNumIntrinsics)
        Jc.col(k) = J.d_intrinsics.col(p);
      else
        Jc.col(k) = J.d_pose.col(p - camera::kNumIntrinsics);
    }
    const Eigen::Matrix<double, N, N> C = e.covariance.template topLeftCorner<N, N>();
    // Coefficient-based (lazy) products: Eigen's blocked GEMM costs more than the arithmetic.
    if constexpr (N > 6) {
      if (e.intrinsics_uncorrelated_with_pose) {  // block-diagonal: half the products
        constexpr int I = N - 6;
        const Eigen::Matrix<double, 2, I> Ji = Jc.template leftCols<I>();
        const Eigen::Matrix<double, 2, 6> Jp = Jc.template rightCols<6>();
        const Eigen::Matrix<double, 2, I> JiC = Ji.lazyProduct(C.template topLeftCorner<I, I>());
        const Eigen::Matrix<double, 2, 6> JpC =
            Jp.lazyProduct(C.template bottomRightCorner<6, 6>());
        S = JiC.lazyProduct(Ji.transpose()) + JpC.lazyProduct(Jp.transpose());
        return;
      }
    }
    const Eigen::Matrix<double, 2, N> JS = Jc.lazyProduct(C);
    S = JS.lazyProduct(Jc.transpose());
  });
  return S;
}

void add_observation_loadings(const CalibrationFactors& f, int slot,
                              const Eigen::Matrix<double, 3, 2>& K,
                              const camera::ProjectionJacobians& J, Loadings3& loadings,
                              Eigen::Matrix3d& cov_intrinsic, Eigen::Matrix3d& cov_extrinsic) {
  const auto& cf = f.camera(slot);
  // B = G F over the camera's column blocks (its own ones when the factors are uncoupled).
  const CameraSensitivity G = point_sensitivity(K, J);
  if (cf.intrinsic.cols() > 0) {
    // Over the estimated intrinsics only: the fixed ones' factor rows are zero.
    Eigen::Matrix<double, 3, camera::kNumIntrinsics> G_estimated;
    for (int k = 0; k < cf.num_estimated_intrinsics; ++k)
      G_estimated.col(k) = G.col(cf.estimated_intrinsics[static_cast<size_t>(k)]);
    with_fixed_size<1, camera::kNumIntrinsics>(cf.num_estimated_intrinsics, [&](auto size) {
      constexpr int N = decltype(size)::value;
      add_camera_block<N>(G_estimated.template leftCols<N>(), cf.estimated_intrinsic_rows,
                          cf.intrinsic_begin, loadings, f.coupled() ? nullptr : &cov_intrinsic);
    });
  }
  if (cf.extrinsic.cols() > 0)
    add_camera_block<6>(G.rightCols<6>(), cf.extrinsic, cf.extrinsic_begin, loadings,
                        f.coupled() ? nullptr : &cov_extrinsic);
}

}  // namespace storetrack::uncertainty
