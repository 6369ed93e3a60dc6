// Is the calibration's stated uncertainty the whole story, or does the lens model's error dominate?
// Two checks per camera (docs/calibration.md, "Model error"):
// - cross-validation, after mrcal (http://mrcal.secretsauce.net/tour-cross-validation.html):
//   the views split into two independent halves (alternate views in frame order), each half
//   calibrated alone, and the projection difference between the halves (compare's, with the
//   implied rigid motion fitted out) tested per image cell against the uncertainty of the
//   difference (the halves are independent: the sum of their propagated covariances);
// - the residual map: the fit's residuals binned over the image, each cell's mean residual tested
//   against the noise level (residual sigma / sqrt(n)).
// Per cell chi-square(2) at 1 - cell_false_alarm names the region. Per camera, cross-validation
// alarms on the joint chi-square of all cells (p < camera_false_alarm), the residual map when more
// cells are flagged than a binomial count band allows (docs/calibration.md states the levels).
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "storetrack/calib/intrinsic_calibration.hpp"
#include "storetrack/calib/observations.hpp"

namespace storetrack::calib {

struct ModelErrorOptions {
  int columns = 8, rows = 4;  ///< cells over the image
  /// A cell is tested with at least this many used points of the full calibration in it (the
  /// observed region: elsewhere a model is extrapolated, not checked).
  int min_points_per_cell = 10;
  double cell_false_alarm = 0.01;  ///< per cell: chi-square(2) quantile at 1 - this
  /// Per check and camera: alarm when the flagged cells exceed the upper end of the binomial
  /// (cells tested, cell_false_alarm) band with this probability above it.
  double camera_false_alarm = 0.005;
};

struct ModelErrorCell {
  int column = 0, row = 0;
  Eigen::Vector2d centre_px = Eigen::Vector2d::Zero();
  int points = 0;       ///< used points of the full calibration in the cell
  bool tested = false;  ///< enough points (and, cross-validation, both halves project)
  /// Residual map: mean residual (observed - projected) [px]; cross-validation: projection
  /// difference half b - half a at the cell centre [px].
  Eigen::Vector2d value_px = Eigen::Vector2d::Zero();
  double rms_px = 0;    ///< residual map: RMS residual per axis in the cell [px]
  double sigma_px = 0;  ///< the standard uncertainty the value is tested against (per axis, rms)
  double chi2 = 0;      ///< value^T C^-1 value, chi-square(2) under noise only
  bool flagged = false;
};

struct ModelErrorTest {
  int columns = 0, rows = 0;
  std::vector<ModelErrorCell> cells;  ///< row-major
  double cell_threshold = 0;          ///< chi-square(2) quantile
  int tested_cells = 0, flagged_cells = 0;
  int allowed_cells = 0;  ///< upper end of the binomial band
  /// Cross-validation only: the cells' differences share the halves' parameter errors, so their
  /// flags are correlated and the count band is no test (measured: 9 alarms in 300 noise-only
  /// seeds at a nominal 0.5 %). The verdict uses the joint chi-square of all tested cells'
  /// differences against their joint covariance (pseudo-inverse over the directions above
  /// 1e-3 of the strongest, as compare's joint test), its dof and p-value.
  double joint_chi2 = 0;
  int joint_dof = 0;
  double joint_p_value = 1;
  bool model_error = false;
  bool available = false;  ///< false: could not be run (reason says why)
  std::string reason;
};

struct ModelErrorCheck {
  int camera_id = 0;
  ModelErrorTest cross_validation, residual_map;
  double cross_validation_distance_m = 0;  ///< depth of the difference (median board depth)
  bool model_error = false;                ///< either check alarms
  /// "noise dominates" or "model error dominates here: <cells>" (one line, per camera).
  std::string verdict;
};

/// Residual map of one camera: `residuals` (of a fit of `camera` to `set`) binned by the observed
/// pixel, each residual normalised by weighting_sigma_px * residual_sigma.
ModelErrorTest residual_map_test(const ObservationSet& set, int camera,
                                 const std::vector<PointResidual>& residuals, int width, int height,
                                 double residual_sigma, const ModelErrorOptions& o);

/// Cross-validation of `camera`: the frames in `frames` (the views the full fit used) split
/// alternately, each half calibrated with `options`; the cells where `residual_cells` says the
/// full fit had points are tested.
ModelErrorTest cross_validation_test(const ObservationSet& set, int camera,
                                     const std::vector<int>& frames,
                                     const IntrinsicOptions& options,
                                     const ModelErrorTest& residual_cells,
                                     const ModelErrorOptions& o, double& distance_m);

/// Both checks and the camera's verdict.
ModelErrorCheck check_model_error(const ObservationSet& set, int camera,
                                  const std::vector<int>& frames,
                                  const std::vector<PointResidual>& residuals, int width,
                                  int height, double residual_sigma,
                                  const IntrinsicOptions& options, const ModelErrorOptions& o);

}  // namespace storetrack::calib
