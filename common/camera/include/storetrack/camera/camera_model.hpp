// Central camera model, OpenCV-compatible (docs/conventions.md, "Camera model"): pinhole +
// Brown-Conrady (rational) or Kannala-Brandt (fisheye) lens behind one interface, so that every
// consumer (projection, triangulation, uncertainty, calibration) handles both without its own
// code path. Pure math: no I/O here (calibration files are in calibration_file.hpp).
#pragma once

#include <array>
#include <optional>
#include <string_view>

#include <Eigen/Core>

#include "storetrack/geometry/transform.hpp"

namespace storetrack::camera {

/// The lens model: how a ray at angle theta from the optical axis maps to the image plane.
enum class LensModel {
  /// OpenCV's pinhole + Brown-Conrady with the rational radial term: dist = (k1, k2, p1, p2, k3,
  /// k4, k5, k6). Follows r = tan(theta); runs out towards wide angles.
  kRationalBrown,
  /// Kannala & Brandt, IEEE PAMI 28(8) 2006, in OpenCV's cv::fisheye form: theta_d = theta (1 +
  /// k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8), dist = (k1, k2, k3, k4, 0, 0, 0, 0).
  /// Rays with theta < 90 degrees (Z > 0).
  kKannalaBrandt,
};

/// Intrinsic parameters. The packed intrinsic vector used by Jacobians and covariances is
/// (fx, fy, cx, cy, skew, dist[0..7]): kNumIntrinsics entries, dist as the lens model says
/// (Kannala-Brandt: entries 9..12 unused, their derivatives zero).
struct Intrinsics {
  double fx = 1000, fy = 1000;    ///< focal lengths [px]
  double cx = 959.5, cy = 511.5;  ///< principal point [px], pixel-centre origin
  double skew = 0;                ///< [px]
  /// Lens coefficients, order of `lens_model` (rational Brown: OpenCV's k1, k2, p1, p2, k3, k4,
  /// k5, k6, k4..k6 the rational denominator; Kannala-Brandt: k1..k4).
  std::array<double, 8> dist{};
  int width = 1920, height = 1024;  ///< image size [px]
  LensModel lens_model = LensModel::kRationalBrown;
};

/// Number of lens coefficients `model` uses (dist[0..n-1]).
int lens_coefficient_count(LensModel model);
/// The model's name in calibration files and on the command line: "rational-brown",
/// "kannala-brandt".
const char* lens_model_name(LensModel model);
/// The model of a name; nullopt for an unknown one.
std::optional<LensModel> lens_model_from_name(std::string_view name);

inline constexpr int kNumIntrinsics = 13;
using IntrinsicVector = Eigen::Matrix<double, kNumIntrinsics, 1>;
using IntrinsicCovariance = Eigen::Matrix<double, kNumIntrinsics, kNumIntrinsics>;

IntrinsicVector pack(const Intrinsics& in);
/// The intrinsics of a packed vector; the lens model and image size are not in it.
Intrinsics unpack(const IntrinsicVector& v, int width, int height, LensModel lens_model);

/// Optional Jacobians of a projection u = project(T_c_w * p_w).
struct ProjectionJacobians {
  Eigen::Matrix<double, 2, 3> d_point_cam;    ///< du/dp_cam
  Eigen::Matrix<double, 2, 3> d_point_world;  ///< du/dp_w (through R_c_w)
  Eigen::Matrix<double, 2, 6> d_pose;  ///< du/d(left perturbation of T_c_w) (rx,ry,rz,tx,ty,tz)
  Eigen::Matrix<double, 2, kNumIntrinsics> d_intrinsics;  ///< du/d(packed intrinsics)
};

class CameraModel {
 public:
  CameraModel() = default;
  explicit CameraModel(const Intrinsics& intrinsics) : in_(intrinsics) {}

  const Intrinsics& intrinsics() const { return in_; }

  /// Camera-frame point -> pixels; nullopt when Z <= 0 (Kannala-Brandt: on the -Z axis only).
  /// d_point_cam / d_intrinsics are filled when non-null.
  std::optional<geometry::Vec2> project(
      const geometry::Vec3& p_cam, Eigen::Matrix<double, 2, 3>* d_point_cam = nullptr,
      Eigen::Matrix<double, 2, kNumIntrinsics>* d_intrinsics = nullptr) const;

  /// Projects a world point through the extrinsics T_c_w; all Jacobians optional.
  std::optional<geometry::Vec2> project_world(const geometry::Transform& T_c_w,
                                              const geometry::Vec3& p_w,
                                              ProjectionJacobians* jacobians = nullptr) const;

  /// Removes distortion: pixel -> normalised image point (x, y) with Z = 1. Iterative (rational
  /// Brown: Gauss-Newton on the distortion map; Kannala-Brandt: Newton on theta); returns nullopt
  /// if it does not converge to `tolerance_px` (re-projected) within max_iterations, or if the
  /// root is not the physical ray (beyond the lens map's fold; Kannala-Brandt: theta >= 90 deg or
  /// theta_d(theta) not increasing on [0, theta]).
  std::optional<geometry::Vec2> unproject(const geometry::Vec2& pixel, double tolerance_px = 1e-6,
                                          int max_iterations = 20) const;

  /// Distorts a normalised point (x, y) -> (x', y') (Kannala-Brandt: (x, y) theta_d / r), with
  /// the optional 2x2 Jacobian.
  geometry::Vec2 distort(const geometry::Vec2& xy, geometry::Mat2* d_xy = nullptr) const;

  /// Distortion-free ("undistorted") pixel of a normalised point: K (x, y, 1), with the same
  /// fx, fy, cx, cy, skew. Used by matching, where epipolar lines are straight.
  geometry::Vec2 ideal_pixel(const geometry::Vec2& xy) const;

  /// d(x, y)/d(pixel) of unproject, evaluated at the normalised point xy it returned
  /// (inverse of the forward Jacobian d pixel/d(x, y)); propagates centroid covariance.
  geometry::Mat2 unproject_jacobian(const geometry::Vec2& xy) const;

 private:
  Intrinsics in_{};
};

/// A calibrated camera of the rig: intrinsics, extrinsics T_c_w and their covariances.
struct CalibratedCamera {
  int camera_id = 0;
  int unit_id = 0;
  CameraModel model;
  geometry::Transform T_c_w = geometry::Transform::Identity();
  IntrinsicCovariance intrinsic_covariance = IntrinsicCovariance::Zero();
  /// Covariance of the left perturbation (rx, ry, rz, tx, ty, tz) of T_c_w.
  geometry::Mat6 extrinsic_covariance = geometry::Mat6::Zero();
  double exposure_offset_ns = 0;        ///< known trigger latency of this camera (calibrated)
  double exposure_offset_sigma_ns = 0;  ///< its standard uncertainty (sync jitter)
};

/// Pixel of a surveyed body point p_b (body frame) through the body pose T_w_b and a calibrated
/// camera: the measurement a mark seen by one camera makes of its body's pose (docs/matching.md,
/// single views). When non-null, `d_body_pose` gets d pixel / d(left perturbation of T_w_b)
/// (rx, ry, rz, tx, ty, tz; geometry::perturb_left) = d pixel / d p_w [-[R p_b]x, I], and
/// `jacobians` the camera's projection Jacobians at the point (calibration propagation).
/// nullopt when the point is behind the camera.
std::optional<geometry::Vec2> project_body_point(const CalibratedCamera& camera,
                                                 const geometry::Transform& T_w_b,
                                                 const geometry::Vec3& p_b,
                                                 Eigen::Matrix<double, 2, 6>* d_body_pose = nullptr,
                                                 ProjectionJacobians* jacobians = nullptr);

}  // namespace storetrack::camera
