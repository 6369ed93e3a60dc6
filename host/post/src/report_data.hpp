// The data of storetrack-post's truth-free report (--report DIR, docs/post-processing.md): per
// exposure and camera, which camera delivered and its reprojection residuals normalised by the
// processor's own predicted spread; per exposure, the rigid-body fit chi-square; per camera and
// window, the RMS of the normalised residuals against its chi-square band. Taken from the
// processor's ExposureResult (residuals and information matrices), nothing recomputed.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/pipeline/aligned_exposure.hpp"
#include "storetrack/pipeline/exposure_result.hpp"

namespace storetrack::post {

/// One camera of the rig at one processed exposure.
struct CameraResidualRow {
  std::uint32_t trigger_seq = 0;
  std::int64_t t_tai_ns = 0;  ///< the exposure's reference mid-point
  int camera_id = -1;
  bool delivered = false;  ///< false: the aligner closed the exposure without it
  int marks_reported = 0;  ///< marks the camera sent
  int residuals = 0;       ///< its views used in a triangulation (marks seen by >= 2 cameras)
  /// Sum over those views of r^T W r (W: the triangulation's weight of the view, its predicted
  /// spread including the calibration's pixel covariance).
  double chi2 = 0;
  /// Its expected value: sum over the views of 2 - h, h the view's leverage in its mark's
  /// triangulation, trace(J (sum_j J_j^T W_j J_j)^-1 J^T W) with J = d pixel / d p_w at the
  /// triangulated point (a mark of n views: 2n - 3 in all).
  double dof = 0;
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

/// The rig's cameras' rows of one exposure, in rig order.
std::vector<CameraResidualRow> camera_residual_rows(const pipeline::AlignedExposure& e,
                                                    const pipeline::ExposureResult& r,
                                                    const camera::RigCalibration& rig);
ExposureRow exposure_row(const pipeline::AlignedExposure& e, const pipeline::ExposureResult& r,
                         bool written);

/// RMS of one camera's normalised residuals over a window of its delivered exposures:
/// sqrt(sum chi2 / sum dof), expected 1; the band holds it with probability 0.95 when the
/// residuals are Gaussian with their predicted spread (chi-square quantiles 0.025 and 0.975
/// for the window's degrees of freedom, rounded).
struct ResidualWindow {
  int camera_id = -1;
  std::uint32_t first_seq = 0, last_seq = 0;
  std::int64_t first_t_tai_ns = 0, last_t_tai_ns = 0;
  int exposures = 0, residuals = 0;
  double chi2 = 0, dof = 0;
  double rms_normalised = 0, band_low = 0, band_high = 0;
  bool inside() const { return rms_normalised >= band_low && rms_normalised <= band_high; }
};
inline constexpr double kResidualBandProbability = 0.95;

/// Consecutive windows of `window` delivered exposures per camera (a last, shorter window
/// is dropped); windows without residuals are skipped.
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
