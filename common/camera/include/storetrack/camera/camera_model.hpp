// Pinhole + Brown-Conrady camera model, OpenCV-compatible (docs/conventions.md, "Camera model").
// Pure math: no I/O here (calibration files are in calibration_file.hpp).
#pragma once

#include <array>
#include <optional>

#include <Eigen/Core>

#include "storetrack/geometry/transform.hpp"

namespace storetrack::camera {

/// Intrinsic parameters. The packed intrinsic vector used by Jacobians and covariances is
/// (fx, fy, cx, cy, skew, k1, k2, p1, p2, k3, k4, k5, k6): kNumIntrinsics entries.
struct Intrinsics {
  double fx = 1000, fy = 1000;    ///< focal lengths [px]
  double cx = 959.5, cy = 511.5;  ///< principal point [px], pixel-centre origin
  double skew = 0;                ///< [px]
  /// OpenCV order k1, k2, p1, p2, k3, k4, k5, k6 (k4..k6: rational model denominator).
  std::array<double, 8> dist{};
  int width = 1920, height = 1024;  ///< image size [px]
};

inline constexpr int kNumIntrinsics = 13;
using IntrinsicVector = Eigen::Matrix<double, kNumIntrinsics, 1>;
using IntrinsicCovariance = Eigen::Matrix<double, kNumIntrinsics, kNumIntrinsics>;

IntrinsicVector pack(const Intrinsics& in);
Intrinsics unpack(const IntrinsicVector& v, int width, int height);

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

  /// Projects a point in the camera frame to pixels. Returns nullopt when Z <= 0.
  /// d_point_cam / d_intrinsics are filled when non-null.
  std::optional<geometry::Vec2> project(
      const geometry::Vec3& p_cam, Eigen::Matrix<double, 2, 3>* d_point_cam = nullptr,
      Eigen::Matrix<double, 2, kNumIntrinsics>* d_intrinsics = nullptr) const;

  /// Projects a world point through the extrinsics T_c_w; all Jacobians optional.
  std::optional<geometry::Vec2> project_world(const geometry::Transform& T_c_w,
                                              const geometry::Vec3& p_w,
                                              ProjectionJacobians* jacobians = nullptr) const;

  /// Removes distortion: pixel -> normalised image point (x, y) with Z = 1. Iterative
  /// (Gauss-Newton on the distortion map); returns nullopt if it does not converge to
  /// `tolerance_px` (re-projected) within max_iterations.
  std::optional<geometry::Vec2> unproject(const geometry::Vec2& pixel, double tolerance_px = 1e-6,
                                          int max_iterations = 20) const;

  /// Distorts a normalised point (x, y) -> (x', y'), optional 2x2 Jacobian.
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
