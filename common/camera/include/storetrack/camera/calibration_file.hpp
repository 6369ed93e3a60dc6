// Rig calibration file (JSON, docs/calibration-file.md): cameras' intrinsics, extrinsics T_c_w
// and covariances; version 2 adds the joint covariance of all cameras' parameters. Read by the
// host; written by storetrack-calib and the simulator. Versions 1 and 2 are read, 2 is written.
#pragma once

#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "storetrack/camera/camera_model.hpp"

namespace storetrack::camera {

/// Thrown by the readers on malformed files; what() names the file, the JSON path and why.
class CalibrationFileError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Parameters per camera in the joint covariance: the 13 packed intrinsics, then the left
/// perturbation (rx, ry, rz, tx, ty, tz) of T_c_w.
inline constexpr int kJointBlockSize = kNumIntrinsics + 6;

/// Where a calibration had observations in one camera's image (docs/calibration-file.md,
/// "observed_region"): the image split into `columns` x `rows` equal cells, the number of
/// observed points per cell (row-major). A model is backed by data only in cells with points;
/// `compare` evaluates differences there (issue 28).
struct ObservedRegion {
  int columns = 16, rows = 8;
  std::vector<int> counts;  ///< rows * columns, row-major; empty = not recorded

  /// The cell of `pixel` in a width x height image (pixel centres at integers, conventions.md),
  /// or -1 outside the image.
  int cell_of(const Eigen::Vector2d& pixel, int width, int height) const;
  /// True when `pixel` falls in a cell with at least `min_points` observed points.
  bool contains(const Eigen::Vector2d& pixel, int width, int height, int min_points = 1) const;
};

/// The grid of `pixels` in a width x height image (points outside the image are not counted).
ObservedRegion observed_region_of(const std::vector<Eigen::Vector2d>& pixels, int width, int height,
                                  int columns = 16, int rows = 8);

struct RigCalibration {
  std::vector<CalibratedCamera> cameras;
  /// Observed region per camera_id (optional per camera; files before issue 28 have none).
  std::map<int, ObservedRegion> observed_regions;
  /// Joint covariance of every camera's parameters (file version 2): kJointBlockSize rows per
  /// camera, cameras in `cameras` order. Empty = none (version 1: cameras independent, no
  /// intrinsic-extrinsic correlation). Its diagonal 13x13 / 6x6 blocks equal the cameras'
  /// intrinsic_covariance / extrinsic_covariance (set_joint_covariance keeps them so).
  Eigen::MatrixXd joint_covariance;

  const CalibratedCamera* find(int camera_id) const;
  /// The joint covariance; without one, block diagonal from the cameras' blocks.
  Eigen::MatrixXd full_joint_covariance() const;
  /// True when the joint covariance has a nonzero term outside the cameras' 13x13 and 6x6
  /// blocks (cross-camera or intrinsic-extrinsic correlation).
  bool has_cross_covariance() const;
};

/// Stores `joint` (layout of RigCalibration::joint_covariance) and copies its diagonal blocks
/// into the cameras' intrinsic_covariance / extrinsic_covariance. Throws std::invalid_argument
/// on a wrong size.
void set_joint_covariance(RigCalibration& rig, const Eigen::MatrixXd& joint);

RigCalibration read_rig_calibration(const std::string& path);
RigCalibration parse_rig_calibration(const std::string& json_text, const std::string& origin);
void write_rig_calibration(const RigCalibration& rig, const std::string& path);
std::string format_rig_calibration(const RigCalibration& rig);

}  // namespace storetrack::camera
