// Triangulation of one mark from 2..N calibrated cameras (docs/uncertainty.md).
//
// Linear initialisation (DLT on undistorted normalised coordinates, Hartley & Zisserman,
// "Multiple View Geometry", 12.2), then Gauss-Newton on the reprojection error weighted by the
// centroid standard uncertainty, with the projection Jacobian of Leizea et al. (Sensors 2023,
// 23, 589): J_k = D_P R_k. At the solution the centroid covariance is (J^T W J)^-1 and the
// gain K_k = (J^T W J)^-1 J_k^T W_k gives dp/d(pixel_k), from which the host propagates the
// calibration and synchronisation errors (first-order, GUM JCGM 100:2008, 5.1).
#pragma once

#include <optional>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "storetrack/camera/camera_model.hpp"
#include "storetrack/geometry/transform.hpp"

namespace storetrack::triangulate {

/// One camera's sighting of the mark.
struct Observation {
  const camera::CameraModel* model = nullptr;
  geometry::Transform T_c_w = geometry::Transform::Identity();
  geometry::Vec2 pixel_px = geometry::Vec2::Zero();
  double sigma_px = 0.1;  ///< centroid standard uncertainty per axis
  /// Full pixel information matrix (inverse covariance, e.g. centroid plus calibration part)
  /// replacing sigma_px^-2 I in the refinement, chi2, covariance and gains when set.
  std::optional<geometry::Mat2> information_px;
  /// Known motion of the mark between the reference time and this camera's exposure
  /// (velocity * time offset), world frame: the camera saw p_w + displacement_w.
  geometry::Vec3 displacement_w = geometry::Vec3::Zero();
};

struct Options {
  int max_iterations = 10;
  double step_tolerance_m = 1e-9;  ///< stop when the Gauss-Newton step is shorter
  /// Also fill d_pose / d_intrinsics of Result::jacobians (needed for the calibration budget);
  /// without them only d_point_cam / d_point_world are set.
  bool calibration_jacobians = true;
  /// Starting point of the Gauss-Newton refinement instead of the linear (DLT) estimate, e.g.
  /// the position predicted by tracking (saves the undistortion of every observation). The
  /// refinement converges to the same point; on failure from it the linear start is tried.
  std::optional<geometry::Vec3> initial_p_w;
};

struct Result {
  geometry::Vec3 p_w = geometry::Vec3::Zero();
  geometry::Mat3 cov_centroid = geometry::Mat3::Zero();  ///< (J^T W J)^-1 [m^2]
  double chi2 = 0;                                       ///< sum of weighted squared residuals
  int iterations = 0;
  /// Per observation, in input order:
  std::vector<geometry::Vec2> residual_px;             ///< observed - predicted
  std::vector<camera::ProjectionJacobians> jacobians;  ///< at the solution
  std::vector<Eigen::Matrix<double, 3, 2>> gain;       ///< dp_w / d(pixel)
};

/// Linear (DLT) estimate; nullopt when fewer than 2 usable observations or degenerate rays.
std::optional<geometry::Vec3> triangulate_linear(std::span<const Observation> observations);

/// Linear initialisation + Gauss-Newton. Returns false (out untouched beyond scratch) when the
/// linear step fails, the point ends up behind a camera or the normal matrix is singular.
bool triangulate(std::span<const Observation> observations, const Options& options, Result& out);

}  // namespace storetrack::triangulate
