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

/// A view's projection of the refinement's start point (Options::initial_p_w, without the
/// view's displacement) and d pixel / d p_w there, when the caller has them already.
struct StartProjection {
  geometry::Vec2 pixel_px = geometry::Vec2::Zero();
  Eigen::Matrix<double, 2, 3> d_pixel_d_point_w = Eigen::Matrix<double, 2, 3>::Zero();
};

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
  /// The projection at the start point (e.g. the matcher's gate projected the prediction): the
  /// first Gauss-Newton pass from initial_p_w uses it, moved by the displacement to first
  /// order, instead of projecting again (the later passes linearise exactly).
  const StartProjection* start = nullptr;
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
  /// (J^T W J)^-1 [m^2]: the point's covariance under the weights' own error model (centroid
  /// plus, where information_px carries it, the calibration's pixel part); the matcher's gates
  /// and tracks use it.
  geometry::Mat3 cov_weighted = geometry::Mat3::Zero();
  /// sum_k K_k sigma_k^2 K_k^T [m^2]: the centroid noise alone through the estimator's gains
  /// (equal to cov_weighted when every weight is sigma_px^-2 I); the calibration's part is
  /// propagated separately through the same gains (estimation/uncertainty).
  geometry::Mat3 cov_centroid = geometry::Mat3::Zero();
  double chi2 = 0;  ///< sum of weighted squared residuals
  int iterations = 0;
  /// Per observation, in input order:
  std::vector<geometry::Vec2> residual_px;             ///< observed - predicted
  std::vector<camera::ProjectionJacobians> jacobians;  ///< at the solution
  std::vector<Eigen::Matrix<double, 3, 2>> gain;       ///< dp_w / d(pixel)

  /// As constructed, the per-view vectors emptied with their storage kept (reused results).
  void clear() {
    p_w.setZero();
    cov_weighted.setZero();
    cov_centroid.setZero();
    chi2 = 0;
    iterations = 0;
    residual_px.clear();
    jacobians.clear();
    gain.clear();
  }
};

/// Linear (DLT) estimate; nullopt when fewer than 2 usable observations or degenerate rays.
std::optional<geometry::Vec3> triangulate_linear(std::span<const Observation> observations);

/// Two-view midpoint of already-formed rays (centre c, direction d, any length; world frame):
/// the point halfway between the closest points c1 + s d1 and c2 + t d2 of the two lines. The
/// cheap start of host/match's re-acquisition pre-gate, where every ray is formed once per
/// observation and triangulate_linear would undistort each pixel again per pair. nullopt when
/// the rays are (nearly) parallel or the closest points are not in front of both centres.
inline std::optional<geometry::Vec3> ray_midpoint(const geometry::Vec3& c1,
                                                  const geometry::Vec3& d1,
                                                  const geometry::Vec3& c2,
                                                  const geometry::Vec3& d2) {
  // Normal equations of min |c1 + s d1 - c2 - t d2|^2 over (s, t), solved by Cramer's rule.
  const geometry::Vec3 r = c1 - c2;
  const double a = d1.dot(d1), b = d1.dot(d2), c = d2.dot(d2), d = d1.dot(r), e = d2.dot(r);
  const double den = a * c - b * b;
  if (!(den > 1e-12 * a * c)) return std::nullopt;  // (nearly) parallel rays
  const double s = (b * e - c * d) / den, t = (a * e - b * d) / den;
  if (!(s > 0 && t > 0)) return std::nullopt;
  return geometry::Vec3(0.5 * (c1 + s * d1 + c2 + t * d2));
}

/// Linear initialisation + Gauss-Newton. Returns false (out untouched beyond scratch) when the
/// linear step fails, the point ends up behind a camera or the normal matrix is singular.
bool triangulate(std::span<const Observation> observations, const Options& options, Result& out);

}  // namespace storetrack::triangulate
