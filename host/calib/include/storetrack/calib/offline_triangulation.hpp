// Offline triangulation (`storetrack-calib triangulate`, docs/calibration.md): a CSV of pixel
// observations and a rig calibration file -> the marks CSV that storetrack-eval reads, each
// mark with its full covariance (centroid + calibration, cross-camera terms included, + the
// exposure-offset sync term when the CSV gives times), by the
// host's own code: estimation/triangulate weighted as the host weighs a view
// (uncertainty::view_information) and the calibration's loadings (CalibrationFactors,
// add_observation_loadings), as host/pipeline's exposure processor does.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "storetrack/calib/observations.hpp"  // ObservationFileError
#include "storetrack/camera/calibration_file.hpp"

namespace storetrack::calib {

/// One row of the pixel-observation CSV (docs/calibration.md, "Triangulate").
struct PixelObservation {
  int line = 0;                         ///< line in the file (messages)
  std::int64_t exposure = 0;            ///< exposure (trigger) number: the marks CSV's trigger_seq
  std::optional<std::int64_t> time_ns;  ///< exposure time, written as reference_mid_tai_ns
  int camera_id = 0;
  int mark_id = 0;
  Eigen::Vector2d pixel_px = Eigen::Vector2d::Zero();
  Eigen::Matrix2d covariance_px = Eigen::Matrix2d::Identity();  ///< of the centroid [px^2]
};

/// Reads the CSV; throws ObservationFileError "<file>:<line>: <field>: <reason>" on a missing
/// column, a malformed or non-finite cell, a covariance that is not positive definite, or a
/// (exposure, camera, mark) given twice.
std::vector<PixelObservation> parse_pixel_observations_csv(const std::string& text,
                                                           const std::string& origin);

struct TriangulatedMark {
  std::int64_t exposure = 0;
  std::optional<std::int64_t> time_ns;
  int mark_id = 0;
  Eigen::Vector3d p_w = Eigen::Vector3d::Zero();
  Eigen::Matrix3d cov_centroid = Eigen::Matrix3d::Zero();
  Eigen::Matrix3d cov_calibration = Eigen::Matrix3d::Zero();  ///< intrinsic + extrinsic
  /// The cameras' exposure-offset uncertainty (exposure_offset_sigma_ns) times the mark's
  /// velocity: zero unless the CSV gives times and the mark is seen in a neighbouring exposure.
  Eigen::Matrix3d cov_sync = Eigen::Matrix3d::Zero();
  std::optional<Eigen::Vector3d> velocity_w;        ///< from the neighbouring exposures [m/s]
  Eigen::Matrix3d cov_w = Eigen::Matrix3d::Zero();  ///< the sum
  std::vector<int> camera_ids;
  std::vector<Eigen::Vector2d> pixels_px, residuals_px;
  std::vector<double> sigmas_px;  ///< sqrt of the mean of the centroid variances (u, v)
  std::vector<int> slots;         ///< the observations' camera slots in the rig
  std::vector<Eigen::Matrix<double, 3, 2>> gains;            ///< dp_w / d(pixel) per observation
  std::vector<Eigen::Matrix<double, 2, 3>> d_pixel_d_point;  ///< per observation
};

struct OfflineTriangulation {
  std::vector<TriangulatedMark> marks;
  int single_camera_marks = 0;  ///< (exposure, mark) seen by one camera: counted, not triangulated
  int failed_marks = 0;         ///< seen by >= 2 cameras, the triangulation failed
};

/// Throws CalibrationError naming `csv_origin`, the line and the camera when a camera id is not
/// in `rig` (`rig_origin`).
OfflineTriangulation triangulate_observations(const camera::RigCalibration& rig,
                                              const std::vector<PixelObservation>& observations,
                                              const std::string& rig_origin,
                                              const std::string& csv_origin);

/// The marks CSV (the host's --marks-csv columns, docs/evaluation.md): one row per mark and
/// camera, body `body` ('p', 's' or '?').
std::string format_marks_csv(const OfflineTriangulation& result, char body);

}  // namespace storetrack::calib
