// Rig calibration: joint bundle adjustment of every camera's intrinsics, every camera's
// extrinsics T_c_r to the reference camera (camera 0, S_r) and every board pose T_r_b, from
// one board set seen by all cameras (docs/calibration.md, "Rig"), with the joint covariance.
#pragma once

#include <vector>

#include "storetrack/calib/intrinsic_calibration.hpp"

namespace storetrack::calib {

struct RigOptions {
  /// Model flags and outlier gate, the same for every camera (as cv::stereoCalibrate's flags);
  /// each camera's intrinsic calibration (the start) uses them too.
  IntrinsicOptions intrinsic;
  /// Fewest frames two cameras must both see (>= 4 points each) for their relative pose to be
  /// initialised from them; a camera linked to the reference by no chain of such pairs is refused.
  int min_common_views = 3;
};

/// Layout of the joint covariance: per camera (in RigResult::cameras order) its 13 packed
/// intrinsics (calibration-file order) then the 6 of the left perturbation of T_c_r
/// (rx, ry, rz, tx, ty, tz); the reference camera's 6 are zero (S_r is defined by it).
inline constexpr int kRigBlockSize = camera::kNumIntrinsics + 6;

struct RigViewResult {
  int frame = 0;
  int points_used = 0, points_rejected = 0;
  double rms_px = 0;
};

struct RigCameraResult {
  int camera_id = 0;
  camera::Intrinsics intrinsics;
  geometry::Transform T_c_r = geometry::Transform::Identity();  ///< reference -> this camera
  camera::IntrinsicCovariance intrinsic_covariance = camera::IntrinsicCovariance::Zero();
  geometry::Mat6 extrinsic_covariance = geometry::Mat6::Zero();  ///< left perturbation of T_c_r
  double baseline_m = 0;        ///< |t_c_r|: distance of the optical centre from S_r's origin
  double baseline_sigma_m = 0;  ///< its standard uncertainty (first order)
  std::vector<RigViewResult> views;
  std::vector<PointResidual> residuals;    ///< observed - projected, rejected points flagged
  std::vector<SkippedView> views_skipped;  ///< this camera's degenerate views: unused
  int points_used = 0, points_rejected = 0;
  double rms_px = 0;        ///< sqrt(SSR / N) over this camera's used points
  double start_rms_px = 0;  ///< its own intrinsic calibration's (the start; a lower bound)
  int common_views_with_reference = 0;
};

struct RigResult {
  std::vector<RigCameraResult> cameras;    ///< ascending camera id; cameras[0] is the reference
  std::vector<int> frames;                 ///< board poses estimated (frames seen by any camera)
  std::vector<geometry::Transform> T_r_b;  ///< per frame, board -> reference camera
  /// kRigBlockSize * cameras x the same: s^2 (J^T W J)^-1 over all intrinsics and extrinsics,
  /// board poses eliminated exactly (Schur complement), fixed parameters 0.
  Eigen::MatrixXd joint_covariance;
  BoardDeflectionResult board_deflection;  ///< one board: fitted jointly over every camera
  int points_used = 0, points_rejected = 0;
  /// free intrinsics + 6 per non-reference camera + 6 per frame (+ 2 with the board deflection)
  int free_parameters = 0;
  double rms_px = 0;             ///< over all cameras' used points
  double residual_sigma_px = 0;  ///< sqrt(SSR_w / (2N - p)); its square scales the covariance
  int iterations = 0;
};

/// Calibrates every camera in `set` jointly; camera 0 is the reference. Throws CalibrationError
/// naming the camera when one cannot be calibrated or linked to the reference.
RigResult calibrate_rig(const ObservationSet& set, const RigOptions& options);

}  // namespace storetrack::calib
