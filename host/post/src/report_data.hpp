// The data of storetrack-post's truth-free report (--report DIR, docs/post-processing.md): per
// exposure and camera, which camera delivered; per exposure, the rigid-body fit chi-square; the
// reprojection residuals split into their two parts (docs/post-processing.md derives both):
// - the NOISE part, per camera and window: differences of a mark's residuals at two consecutive
//   exposures (the calibration part cancels) against the centroid noise's predicted spread;
// - the SHARED (calibration) part, one figure per camera for the whole recording: each mark's
//   mean residual against the calibration's stated contribution (cross terms between cameras
//   included, through the processor's CalibrationFactors) plus the mean's noise.
// Taken from the processor's ExposureResult (residuals and weights); the predicted covariances
// are R = (I - A) S (I - A)^T over a mark's views, A the triangulation's hat matrix.
#pragma once

#include <cstdint>
#include <map>
#include <span>
#include <tuple>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/pipeline/aligned_exposure.hpp"
#include "storetrack/pipeline/exposure_result.hpp"
#include "storetrack/uncertainty/calibration_factors.hpp"

namespace storetrack::post {

/// One camera of the rig at one processed exposure.
struct CameraResidualRow {
  std::uint32_t trigger_seq = 0;
  std::int64_t t_tai_ns = 0;  ///< the exposure's reference mid-point
  int camera_id = -1;
  bool delivered = false;  ///< false: the aligner closed the exposure without it
  int marks_reported = 0;  ///< marks the camera sent
  int residuals = 0;       ///< its views used in a triangulation (marks seen by >= 2 cameras)
  /// Noise part: the differences d = r_k - r_(k-1) of its views completed at this exposure
  /// (a mark's view paired with the same mark and camera set at the previous exposure; pairs
  /// do not overlap, so they are independent), with sum d^T C^-1 d, C = R_noise,k +
  /// R_noise,k-1 (the view's 2 x 2 block): chi-square with 2 per difference, 1 for a mark of
  /// two views (d along C's major axis: its block has rank 1).
  int differences = 0;
  double noise_chi2 = 0;
  double noise_dof = 0;
};

/// One processed exposure: camera usage and the rigid-body pose fits' chi-square.
struct ExposureRow {
  std::uint32_t trigger_seq = 0;
  std::int64_t t_tai_ns = 0;
  bool written = false;  ///< false: withheld (too few cameras), as live
  int cameras_delivered = 0;
  std::uint32_t missing_camera_mask = 0;  ///< bit i: rig camera i did not deliver
  bool closed_by_timeout = false;
  int store_marks = 0, pylon_marks = 0;   ///< marks in each body's pose fit (0: no pose)
  double store_chi2 = 0, pylon_chi2 = 0;  ///< fit chi-square, 3 n - 6 degrees of freedom
};

ExposureRow exposure_row(const pipeline::AlignedExposure& e, const pipeline::ExposureResult& r,
                         bool written);

/// The shared (calibration) part of one camera's residuals over the recording (over each span of
/// one calibration, when correct mode rebuilt the processor): the mean
/// residual of each mark it saw, stacked, r_bar ~ N(0, M_bar M_bar^T + N_bar) when the
/// calibration is one draw from its stated covariance (M_bar: the mean of the views' residual
/// loadings (I - A) P on the calibration factors; N_bar: the means' noise). chi2 = r_bar^T
/// (M_bar M_bar^T + N_bar)^-1 r_bar is ONE chi-square draw of 2 x marks degrees of freedom:
/// its band is that distribution's 0.025 .. 0.975 quantiles (no count over windows).
struct CalibrationResidual {
  int camera_id = -1;
  /// The calibration the residuals were processed with: 0 as recorded, k after the processor's
  /// k-th rebuild on a corrected rig (calibration health, correct mode); one row per camera and
  /// span, since a mean residual over two calibrations tests neither.
  int span = 0;
  std::uint32_t first_trigger_seq = 0, last_trigger_seq = 0;  ///< the span's exposures
  int marks = 0;                                              ///< marks with a mean residual
  int views = 0;                                              ///< views averaged
  double chi2 = 0, dof = 0;
  /// Chi-square quantiles with band_probability between: calibration_band_probability(rows).
  double band_low = 0, band_high = 0, band_probability = 0;
  /// The share of the predicted mean-residual variance that is the calibration's (trace
  /// M_bar M_bar^T / trace of the whole): near 0 the figure tests the noise, not the calibration.
  double calibration_share = 0;
  bool inside() const { return chi2 >= band_low && chi2 <= band_high; }
};

/// Accumulates both residual parts over a recording's processed exposures, in order.
class ResidualDiagnostics {
 public:
  /// `factors`: the processor's (ExposureProcessor::factors()), so the calibration part is the
  /// same calibration errors its stated uncertainty propagates.
  ResidualDiagnostics(const camera::RigCalibration& rig,
                      const uncertainty::CalibrationFactors& factors);
  /// The rig's cameras' rows of one exposure, in rig order (noise part of the pairs it
  /// completes); accumulates the shared part.
  std::vector<CameraResidualRow> add(const pipeline::AlignedExposure& e,
                                     const pipeline::ExposureResult& r);
  /// The processor was rebuilt on another rig (correct mode) after the last exposure added:
  /// closes the current calibration span (its shared part per camera) and starts a new one with
  /// this rig and its factors; a noise pair never spans the change.
  void use_calibration(const camera::RigCalibration& rig,
                       const uncertainty::CalibrationFactors& factors);
  /// The shared part per calibration span and rig camera with residuals, in that order; every
  /// row's band at 1 - 0.05 / rows (Bonferroni over all of them).
  std::vector<CalibrationResidual> calibration_residuals() const;

  /// One view of a triangulated mark: residual, its noise-only predicted covariance (2 x 2
  /// block of R_noise) and its loadings on the calibration factors (rows of (I - A) P).
  struct View {
    int slot = -1;  ///< the camera's index in the rig (and in the factors)
    /// Rank of the view's residual block: 1 for a mark of two views (its 2 n - 3 = 1 degree of
    /// freedom: both views' residuals lie on their epipolar directions), else 2.
    int rank = 2;
    Eigen::Vector2d residual_px = Eigen::Vector2d::Zero();
    Eigen::Matrix2d noise_cov = Eigen::Matrix2d::Zero();
    Eigen::Matrix<double, 2, Eigen::Dynamic> calibration_loadings;
  };

 private:
  struct Pending {  // the first view of a noise pair
    std::uint32_t trigger_seq = 0;
    std::uint32_t camera_set = 0;
    Eigen::Vector2d residual_px;
    Eigen::Matrix2d noise_cov;
    int rank = 2;
  };
  struct Mean {  // running sums of one (camera, mark) pair's views
    int views = 0;
    int rank = 1;  // the largest of its views' ranks
    Eigen::Vector2d residual_px = Eigen::Vector2d::Zero();
    Eigen::Matrix2d noise_cov = Eigen::Matrix2d::Zero();
    Eigen::Matrix<double, 2, Eigen::Dynamic> loadings;
  };
  camera::RigCalibration rig_;
  uncertainty::CalibrationFactors factors_;
  int span_ = 0;
  std::uint32_t span_first_seq_ = 0, span_last_seq_ = 0;
  bool span_started_ = false;
  std::vector<CalibrationResidual> closed_spans_;  ///< rows of the spans before, bands not set
  using Key = std::tuple<int, char, int>;          // rig slot, mark body, mark id
  std::map<Key, Pending> pending_;
  std::map<Key, Mean> means_;

  void add_view(std::uint32_t seq, const Key& key, std::uint32_t camera_set, const View& v,
                CameraResidualRow& row);
  /// The current span's rows (chi2, dof, share), bands not set.
  std::vector<CalibrationResidual> span_residuals() const;
};

/// The views of one triangulated mark (empty when a view's camera is not in the rig or the
/// point is behind it): the residual covariance split R = (I - A) S (I - A)^T with S the
/// centroid noise (sigma^2 I per view) and the calibration's pixel errors P z (P: each view's
/// loadings on the calibration factors, cross terms between cameras included).
std::vector<ResidualDiagnostics::View> mark_views(const pipeline::MarkResult& m,
                                                  const camera::RigCalibration& rig,
                                                  const uncertainty::CalibrationFactors& factors);

/// RMS of one camera's normalised residual differences (noise part) over a window of its
/// delivered exposures: sqrt(sum chi2 / sum dof), expected 1 (residuals: the differences); the band
/// holds it with probability 0.95 when the residuals are Gaussian with their predicted spread
/// (chi-square quantiles 0.025 and 0.975 for the window's degrees of freedom, rounded).
struct ResidualWindow {
  int camera_id = -1;
  std::uint32_t first_seq = 0, last_seq = 0;
  std::int64_t first_t_tai_ns = 0, last_t_tai_ns = 0;
  int exposures = 0, residuals = 0;  ///< residuals: the differences it holds
  double chi2 = 0, dof = 0;
  double rms_normalised = 0, band_low = 0, band_high = 0;
  bool inside() const { return rms_normalised >= band_low && rms_normalised <= band_high; }
};
inline constexpr double kResidualBandProbability = 0.95;
/// The calibration part's band per camera when `cameras` are tested in one recording: the family
/// holds kResidualBandProbability (Bonferroni), so a clean run names no camera 95 % of the time
/// (with 0.95 per camera, 4 cameras named one 19 % of the time).
inline double calibration_band_probability(int cameras) {
  return 1.0 - (1.0 - kResidualBandProbability) / (cameras > 0 ? cameras : 1);
}

/// Consecutive windows of `window` delivered exposures per camera (a last, shorter window
/// is dropped); windows without differences are skipped.
std::vector<ResidualWindow> residual_windows(std::span<const CameraResidualRow> rows, int window);

/// How many windows hold their band, and the binomial acceptance interval of that count
/// (alpha 0.025 per side) when each does with kResidualBandProbability.
struct WindowsInside {
  std::int64_t windows = 0, inside = 0, band_low = 0, band_high = 0;
  bool acceptable() const { return inside >= band_low && inside <= band_high; }
};
WindowsInside windows_inside(std::span<const ResidualWindow> windows);

/// The rigid-body fit chi-square per exposure against its distribution: the count above its
/// `probability` quantile (3 n - 6 degrees of freedom), and the binomial acceptance interval
/// of that count (alpha 0.025 per side) when the stated spread is right.
struct ChiSquareExceedance {
  std::int64_t fits = 0, above = 0, band_low = 0, band_high = 0;
  double probability = 0.99;
};
ChiSquareExceedance rigid_exceedance(std::span<const ExposureRow> rows, bool store,
                                     double probability = 0.99);

}  // namespace storetrack::post
