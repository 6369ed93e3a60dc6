// Calibration errors common to every mark of an exposure, in whitened ("factor") form.
//
// The intrinsic, extrinsic and time-offset errors of all cameras form one error vector theta,
// theta = F z with z ~ N(0, I). Version-1 calibrations (no cross covariance): F is block
// diagonal, F = V sqrt(Lambda) from the eigen-decomposition of each camera's block. With a
// joint covariance (file version 2: cameras correlated through the shared board poses and world
// registration, intrinsics with extrinsics) the intrinsics of all cameras are factored jointly
// and the extrinsics conditionally on them: theta_I = F_I z_I, theta_E = A z_I + F_E|I z_E with
// A = Sigma_EI F_I^+T and F_E|I the factor of Sigma_EE - A A^T (the Schur complement), so
// F F^T is the whole joint covariance, cross terms included. Every estimate derived from
// the marks of one exposure carries "loadings" d(estimate)/dz; the covariance of any set of
// estimates is then L L^T, which keeps the correlations between marks that share a camera's
// calibration (docs/uncertainty.md). Columns are ordered by source: all intrinsic factors,
// then all extrinsic, then the sync factors (one per camera for its calibrated exposure offset,
// then one per unit for its clock, shared by the unit's cameras), so each source is a range.
#pragma once

#include <array>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/camera/camera_model.hpp"
#include "storetrack/uncertainty/sources.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"

namespace storetrack::uncertainty {

/// Loadings of a 3-vector on the common factors z (3 x num_factors). Row-major: the hot
/// operations (rigid-body pair variances, pose loadings, covariances) combine whole rows, which
/// are then contiguous and vectorise.
using Loadings3 = Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor>;
/// Loadings of a 6-vector (pose perturbation) on the common factors z (6 x num_factors).
using Loadings6 = Eigen::Matrix<double, 6, Eigen::Dynamic, Eigen::RowMajor>;
/// Covariance of one camera's parameters in the joint layout (13 packed intrinsics, then the
/// left perturbation of T_c_w), with the intrinsic-extrinsic cross term.
using CameraCovariance = Eigen::Matrix<double, camera::kJointBlockSize, camera::kJointBlockSize>;
/// d(point)/d(one camera's parameters), joint layout (3 x 19).
using CameraSensitivity = Eigen::Matrix<double, 3, camera::kJointBlockSize>;

class CalibrationFactors {
 public:
  struct CameraFactors {
    int intrinsic_begin = 0;  ///< first column this camera's intrinsics load on
    /// d(packed intrinsics)/dz over columns [intrinsic_begin, intrinsic_begin + cols): the
    /// camera's own columns (uncoupled) or the whole intrinsic range (coupled). Row-major, as
    /// the loadings: B = G F is then evaluated row by row as vectorised sums of F's rows.
    Eigen::Matrix<double, camera::kNumIntrinsics, Eigen::Dynamic, Eigen::RowMajor> intrinsic;
    /// The packed intrinsics whose rows of `intrinsic` are not all zero (those the calibration
    /// estimated: a fixed parameter, the skew or an unused lens coefficient, has a zero row),
    /// ascending, and those rows in that order in `estimated_intrinsic_rows`: a mark's loadings
    /// skip the zero rows (5 of 13 for a rational Brown model without skew, k3..k6).
    std::array<int, camera::kNumIntrinsics> estimated_intrinsics{};
    int num_estimated_intrinsics = 0;
    Eigen::Matrix<double, camera::kNumIntrinsics, Eigen::Dynamic, Eigen::RowMajor>
        estimated_intrinsic_rows;
    int extrinsic_begin = 0;
    /// d(left perturbation of T_c_w)/dz (6 x cols) from extrinsic_begin; coupled with
    /// intrinsic-extrinsic correlation it starts at the intrinsic range.
    Eigen::Matrix<double, 6, Eigen::Dynamic, Eigen::RowMajor> extrinsic;
    int sync_column = -1;     ///< column of the exposure time offset (-1: no sync uncertainty)
    double sync_sigma_s = 0;  ///< standard uncertainty of the exposure time offset [s]
    /// Column of the camera's unit clock, shared by the unit's cameras (one clock, one error).
    /// Its sigma is not the calibration's: each exposure states it
    /// (MarkObservations.exposure_time_sigma_ns).
    int clock_column = -1;
  };

  CalibrationFactors() = default;
  /// Factorises each camera's covariance blocks. Eigenvalues below `relative_floor` times the
  /// block's largest are treated as zero (parameters held fixed in the calibration).
  explicit CalibrationFactors(const camera::RigCalibration& rig, double relative_floor = 1e-12);

  int num_factors() const { return num_factors_; }
  /// True when cameras share factor columns (a joint covariance with cross terms): a source's
  /// covariance is then L_s L_s^T over its whole column range, not a sum of per-camera blocks.
  bool coupled() const { return coupled_; }
  int num_cameras() const { return static_cast<int>(cameras_.size()); }
  const CameraFactors& camera(int slot) const { return cameras_[static_cast<size_t>(slot)]; }
  /// Column range [begin, begin + count) of one source (kCentroid/kSurvey/kProcess have none: count
  /// 0).
  std::pair<int, int> range(Source s) const { return ranges_[static_cast<size_t>(index(s))]; }
  /// One camera's parameter covariance F_c F_c^T, from the factors themselves (so a pixel
  /// covariance from it and a mark's loadings describe the same calibration errors): the
  /// file's 19 x 19 block, intrinsic-extrinsic cross term included, to the eigenvalue floor.
  const CameraCovariance& camera_covariance(int slot) const {
    return camera_covariances_[static_cast<size_t>(slot)];
  }
  /// The rows and columns of camera_covariance(slot) that are not all zero: the estimated
  /// intrinsics (CameraFactors::estimated_intrinsics), then the 6 pose parameters; their
  /// indices in the joint layout and that covariance block (a pixel covariance skips the rest).
  struct EstimatedCovariance {
    std::array<int, camera::kJointBlockSize> parameters{};
    int count = 0;
    Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, camera::kJointBlockSize,
                  camera::kJointBlockSize>
        covariance;
    /// Its intrinsic-pose block is zero (no cross term): the two diagonal blocks apart.
    bool intrinsics_uncorrelated_with_pose = false;
  };
  const EstimatedCovariance& estimated_covariance(int slot) const {
    return estimated_covariances_[static_cast<size_t>(slot)];
  }
  /// True when the camera's intrinsic and extrinsic errors are correlated (a joint covariance
  /// with that cross term).
  bool intrinsic_extrinsic_correlated(int slot) const {
    return !camera_covariance(slot)
                .block<6, camera::kNumIntrinsics>(camera::kNumIntrinsics, 0)
                .isZero(0.0);
  }

 private:
  std::vector<CameraFactors> cameras_;
  std::vector<CameraCovariance> camera_covariances_;
  std::vector<EstimatedCovariance> estimated_covariances_;
  std::array<std::pair<int, int>, kNumSources> ranges_{};
  int num_factors_ = 0;
  bool coupled_ = false;

  void factor_per_camera(const camera::RigCalibration& rig, double relative_floor);
  void factor_jointly(const camera::RigCalibration& rig, double relative_floor);
  void add_sync_factors(const camera::RigCalibration& rig);
  void compute_camera_covariances();
  void find_estimated_parameters();
};

/// The calibration's covariance of one camera's pixel of a point, J Sigma_c J^T with J = [d
/// pixel / d intrinsics, d pixel / d pose] and Sigma_c = f.camera_covariance(slot) (cross term
/// included). The one implementation: the matcher's gates and the processor's resection weights.
Eigen::Matrix2d pixel_covariance(const CalibrationFactors& f, int slot,
                                 const camera::ProjectionJacobians& J);

/// The weight of camera `slot`'s view of world point p_w in the host's triangulation:
/// (sigma_px^2 I + pixel_covariance at the point)^-1 [px^-2]. False (W untouched) when the point
/// is not imaged or the sum is not positive definite.
inline bool view_information(const CalibrationFactors& f, int slot,
                             const camera::CalibratedCamera& camera, const Eigen::Vector3d& p_w,
                             double sigma_px, Eigen::Matrix2d& W) {
  camera::ProjectionJacobians J;
  if (!camera.model.project_world(camera.T_c_w, p_w, &J)) return false;
  const Eigen::Matrix2d S =
      sigma_px * sigma_px * Eigen::Matrix2d::Identity() + pixel_covariance(f, slot, J);
  return inverse_spd<2>(S, W);
}

/// d(point)/d(camera parameters) of one observation of a triangulated point: -K [d pixel /
/// d intrinsics, d pixel / d pose] (K = d point / d pixel, the triangulation's gain). The one
/// implementation of a point's calibration sensitivity: the loadings below (G F) and the
/// calibration tools' raw-parameter propagation (G Sigma G^T) are built from it.
inline CameraSensitivity point_sensitivity(const Eigen::Matrix<double, 3, 2>& K,
                                           const camera::ProjectionJacobians& J) {
  CameraSensitivity G;
  G.leftCols<camera::kNumIntrinsics>().noalias() = -K * J.d_intrinsics;
  G.rightCols<6>().noalias() = -K * J.d_pose;
  return G;
}

namespace detail {
// out += A L, two columns (one SSE2 / NEON vector of doubles) at a time for all of A's rows, so
// each element of L is loaded once, not once per row of A. Each element's sum keeps one order,
// out + ((A(r, 0) L(0, j) + A(r, 1) L(1, j)) + ...), whatever the width.
template <typename MatA, typename MatL, typename MatOut, int... k>
void add_loadings_rows(const MatA& A, const MatL& L, MatOut& out,
                       std::integer_sequence<int, k...>) {
  constexpr int R = MatA::RowsAtCompileTime;
  static_assert(R > 0, "add_loadings_product: A's rows must be fixed");
  using Pair = Eigen::Array2d;
  const Eigen::Index n = out.cols();
  const double* l = L.data();
  double* o = out.data();
  const Eigen::Index l_stride = L.rowStride(), o_stride = out.rowStride();
  // Row-major storage: a row's columns are adjacent (a single column may be any vector).
  eigen_assert(n < 2 || (L.colStride() == 1 && out.colStride() == 1));
  // A's coefficients broadcast once, not in every pass over two columns.
  std::array<std::array<Pair, sizeof...(k)>, R> a;
  for (int r = 0; r < R; ++r)
    a[r] = {Pair::Constant(A(r, k))...};
  Eigen::Index j = 0;
  for (; j + 2 <= n; j += 2) {
    const Pair lj[] = {Eigen::Map<const Pair>(l + k * l_stride + j)...};
    for (int r = 0; r < R; ++r)
      Eigen::Map<Pair>(o + r * o_stride + j) += (... + (a[r][k] * lj[k]));
  }
  for (; j < n; ++j)
    for (int r = 0; r < R; ++r)
      o[r * o_stride + j] += (... + (A(r, k) * l[k * l_stride + j]));
}
}  // namespace detail

/// out += A L for loadings L (A.cols() x n) and out (A.rows() x n), both row-major, A small and
/// fixed-size: the one kernel of the loadings' products (a mark's G F over a camera's factor
/// columns, a pose's d pose / d point times a mark's loadings, a relative pose's Jacobians times
/// the bodies' loadings). One pass over the columns with A's size fixed: one load and store of
/// out and one load of L per element (an axpy per coefficient of A would load and store each
/// output row A.cols() times, a pass per output row load L A.rows() times).
template <typename MatA, typename MatL, typename MatOut>
void add_loadings_product(const MatA& A, const MatL& L, MatOut&& out) {
  static_assert(MatA::ColsAtCompileTime > 0, "add_loadings_product: A's columns must be fixed");
  detail::add_loadings_rows(A, L, out, std::make_integer_sequence<int, MatA::ColsAtCompileTime>{});
}

/// One camera's observation of a triangulated point: its loadings on the calibration factors,
/// dp/dtheta F with dp/dtheta = -K dproj/dtheta (K = dp/d(pixel), the triangulation's gain; J
/// its projection Jacobians), added over the camera's intrinsic and extrinsic columns. With
/// uncoupled factors the camera owns those columns, so its B B^T is also added to
/// cov_intrinsic / cov_extrinsic (coupled: take covariance_of over the sum instead). The one
/// implementation of a mark's calibration loadings (the host's processor, storetrack-eval lme).
void add_observation_loadings(const CalibrationFactors& f, int slot,
                              const Eigen::Matrix<double, 3, 2>& K,
                              const camera::ProjectionJacobians& J, Loadings3& loadings,
                              Eigen::Matrix3d& cov_intrinsic, Eigen::Matrix3d& cov_extrinsic);

/// Covariance of loadings restricted to one source's columns: L_s L_s^T.
template <typename Derived>
auto covariance_of(const Eigen::MatrixBase<Derived>& loadings, const CalibrationFactors& f,
                   Source s) {
  const auto [begin, count] = f.range(s);
  using Row = typename Derived::PlainObject;
  using Out = Eigen::Matrix<double, Row::RowsAtCompileTime, Row::RowsAtCompileTime>;
  Out out = Out::Zero(loadings.rows(), loadings.rows());
  if (count > 0) {
    // Symmetric: one dot product of (contiguous, for row-major loadings) rows per element.
    const auto block = loadings.middleCols(begin, count);
    for (Eigen::Index r = 0; r < loadings.rows(); ++r)
      for (Eigen::Index c = r; c < loadings.rows(); ++c)
        out(r, c) = out(c, r) = block.row(r).dot(block.row(c));
  }
  return out;
}

}  // namespace storetrack::uncertainty
