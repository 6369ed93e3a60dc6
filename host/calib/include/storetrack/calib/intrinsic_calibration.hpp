// Single-camera intrinsic calibration: Zhang's closed form, then Levenberg-Marquardt (Ceres) of
// the project's camera model (common/camera), outlier rejection and the parameter covariance
// (docs/calibration.md, "Method").
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "storetrack/calib/observations.hpp"
#include "storetrack/camera/camera_model.hpp"

namespace storetrack::calib {

/// Thrown when the observations cannot determine the camera (too few views, degenerate views).
class CalibrationError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// The board's out-of-plane deflection (mrcal's calobject_warp, docs/calibration.md, "Board
/// deflection"): off = the board as given (flat, or its surveyed z), on = fitted (refused if the
/// board cannot determine it), automatic = fitted when the identifiability rule holds.
enum class BoardDeflection { off, on, automatic };

/// Which parameters are estimated; like cv::calibrateCamera's flags. Fixed ones keep their
/// initial value (0 for distortion) and get variance 0 in the covariance.
struct IntrinsicOptions {
  bool fix_aspect_ratio = false;  ///< fx = aspect_ratio * fy (CALIB_FIX_ASPECT_RATIO)
  double aspect_ratio = 1.0;
  bool fix_principal_point = false;  ///< cx, cy at the image centre (CALIB_FIX_PRINCIPAL_POINT)
  bool zero_tangential = false;      ///< p1 = p2 = 0 (CALIB_ZERO_TANGENT_DIST)
  bool fix_k1 = false, fix_k2 = false, fix_k3 = false;
  bool rational = false;  ///< estimate k4..k6 (CALIB_RATIONAL_MODEL); else they are 0
  /// The lens model fitted. Kannala-Brandt estimates its k1..k4 (the Brown flags above do not
  /// apply) from Zhang's pinhole start with k = 0 (docs/calibration.md, "Wide-angle lenses").
  camera::LensModel lens_model = camera::LensModel::kRationalBrown;
  /// Outlier rejection: a point whose squared residual, over the robust residual variance,
  /// exceeds the chi-square (2 dof) quantile at 1 - false_alarm / N is rejected and the fit
  /// repeated. false_alarm = probability of rejecting any point of a clean set; 0 disables.
  double outlier_false_alarm = 0.01;
  int min_views = 3;
  BoardDeflection board_deflection = BoardDeflection::automatic;
};

/// The fitted deflection z = c_x (1 - xn^2) + c_y (1 - yn^2) added to the board's z, with xn, yn
/// the board coordinates scaled to [-1, 1] over [x_min, x_max] x [y_min, y_max]: the bowl's
/// depth at the board's centre is c_x + c_y.
struct BoardDeflectionResult {
  bool fitted = false;
  std::string reason;                             ///< why (not) fitted: the rule that decided
  Eigen::Vector2d c_m = Eigen::Vector2d::Zero();  ///< (c_x, c_y) [m]
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();  ///< [m^2]
  double x_min = 0, x_max = 0, y_min = 0, y_max = 0;     ///< board extent [m]
};

/// Largest |z| of a board point over the board's larger side: the start (Zhang's homographies)
/// uses (x, y) only, which holds for a nearly planar board; the refinement uses the full point.
inline constexpr double kMaxBoardRelief = 0.1;

struct PointResidual {
  int frame = 0, point_id = 0;
  Eigen::Vector2d residual_px = Eigen::Vector2d::Zero();  ///< observed - projected
  bool rejected = false;
};

/// A view (frame) of one camera left out before the fit, and why (view_screening.hpp).
struct SkippedView {
  int frame = 0;
  std::string reason;  ///< e.g. "all 6 points on one board column (x = 0.1 m): ..."
};

struct ViewResult {
  int frame = 0;
  geometry::Transform T_c_b = geometry::Transform::Identity();  ///< board -> camera
  geometry::Mat6 pose_covariance = geometry::Mat6::Zero();      ///< left perturbation of T_c_b
  int points_used = 0, points_rejected = 0;
  double rms_px = 0;  ///< over the view's used points, per point: sqrt(mean |r|^2)
};

struct IntrinsicResult {
  camera::Intrinsics intrinsics;
  camera::IntrinsicCovariance covariance = camera::IntrinsicCovariance::Zero();
  std::vector<ViewResult> views;
  std::vector<PointResidual> residuals;
  std::vector<SkippedView> views_skipped;  ///< no homography or no pose from them: unused
  BoardDeflectionResult board_deflection;
  int points_used = 0, points_rejected = 0;
  int free_parameters = 0;  ///< intrinsic + 6 per view (+ 2 with the board deflection)
  double rms_px = 0;        ///< sqrt(SSR / N) over used points, as cv::calibrateCamera's RMS
  /// sqrt(SSR_w / (2N - p)) over residuals weighted by 1 / sigma_px (1 when the CSV gives no
  /// sigma): per-axis pixels without sigmas, a ratio (~1 when the sigmas are right) with them.
  /// Its square scales the covariance.
  double residual_sigma_px = 0;
  int iterations = 0;
};

/// Calibrates `camera` from its observations (a planar board, z = 0, or a surveyed one whose z
/// stays within kMaxBoardRelief of its extent). Throws CalibrationError.
IntrinsicResult calibrate_intrinsics(const ObservationSet& set, int camera,
                                     const IntrinsicOptions& options);

}  // namespace storetrack::calib
