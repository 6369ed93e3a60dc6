// Pinhole + Brown-Conrady projection (docs/conventions.md, "Camera model").
//
// The distortion model is OpenCV's (Bradski & Kaehler, "Learning OpenCV", ch. 11; D. C. Brown,
// "Decentering distortion of lenses", Photogrammetric Engineering 32(3), 1966), including the
// rational radial term k4..k6, so that parameters from cv::calibrateCamera apply unchanged.
// All Jacobians are analytic and checked against central differences in
// tests/common/camera/test_camera_model.cpp.
#include "storetrack/camera/camera_model.hpp"

#include <cmath>

namespace storetrack::camera {

using geometry::Mat2;
using geometry::Mat3;
using geometry::Vec2;
using geometry::Vec3;

namespace {

// Indices 0..12 into the packed intrinsic vector (camera_model.hpp); all named, some unused (an
// enum, so clang's -Wunused-const-variable does not object).
enum IntrinsicIndex : int { kFx, kFy, kCx, kCy, kSkew, kK1, kK2, kP1, kP2, kK3, kK4, kK5, kK6 };

/// Everything of the distortion map at one normalised point, shared by distort() and the
/// intrinsic Jacobian.
struct DistortionTerms {
  double r2, r4, r6;
  double num, den, radial;
  Vec2 distorted;
  Mat2 d_xy;
};

DistortionTerms distortion_terms(const Intrinsics& in, const Vec2& xy) {
  const auto& d = in.dist;
  const double k1 = d[0], k2 = d[1], p1 = d[2], p2 = d[3], k3 = d[4], k4 = d[5], k5 = d[6],
               k6 = d[7];
  const double x = xy.x(), y = xy.y();
  DistortionTerms t{};
  t.r2 = x * x + y * y;
  t.r4 = t.r2 * t.r2;
  t.r6 = t.r4 * t.r2;
  t.num = 1 + k1 * t.r2 + k2 * t.r4 + k3 * t.r6;
  t.den = 1 + k4 * t.r2 + k5 * t.r4 + k6 * t.r6;
  t.radial = t.num / t.den;
  t.distorted.x() = x * t.radial + 2 * p1 * x * y + p2 * (t.r2 + 2 * x * x);
  t.distorted.y() = y * t.radial + p1 * (t.r2 + 2 * y * y) + 2 * p2 * x * y;

  // d radial / d r2 by the quotient rule.
  const double d_num = k1 + 2 * k2 * t.r2 + 3 * k3 * t.r4;
  const double d_den = k4 + 2 * k5 * t.r2 + 3 * k6 * t.r4;
  const double d_radial = (d_num * t.den - t.num * d_den) / (t.den * t.den);
  t.d_xy(0, 0) = t.radial + 2 * x * x * d_radial + 2 * p1 * y + 6 * p2 * x;
  t.d_xy(0, 1) = 2 * x * y * d_radial + 2 * p1 * x + 2 * p2 * y;
  t.d_xy(1, 0) = 2 * x * y * d_radial + 2 * p1 * x + 2 * p2 * y;
  t.d_xy(1, 1) = t.radial + 2 * y * y * d_radial + 6 * p1 * y + 2 * p2 * x;
  return t;
}

/// d pixel / d(x', y') = upper-triangular part of K.
Mat2 pixel_from_distorted_jacobian(const Intrinsics& in) {
  Mat2 a;
  a << in.fx, in.skew, 0, in.fy;
  return a;
}

Vec2 pixel_from_distorted(const Intrinsics& in, const Vec2& xy_d) {
  return {in.fx * xy_d.x() + in.skew * xy_d.y() + in.cx, in.fy * xy_d.y() + in.cy};
}

}  // namespace

IntrinsicVector pack(const Intrinsics& in) {
  IntrinsicVector v;
  v << in.fx, in.fy, in.cx, in.cy, in.skew, in.dist[0], in.dist[1], in.dist[2], in.dist[3],
      in.dist[4], in.dist[5], in.dist[6], in.dist[7];
  return v;
}

Intrinsics unpack(const IntrinsicVector& v, int width, int height) {
  Intrinsics in;
  in.fx = v[kFx];
  in.fy = v[kFy];
  in.cx = v[kCx];
  in.cy = v[kCy];
  in.skew = v[kSkew];
  for (int i = 0; i < 8; ++i)
    in.dist[i] = v[kK1 + i];
  in.width = width;
  in.height = height;
  return in;
}

Vec2 CameraModel::distort(const Vec2& xy, Mat2* d_xy) const {
  const DistortionTerms t = distortion_terms(in_, xy);
  if (d_xy) *d_xy = t.d_xy;
  return t.distorted;
}

Vec2 CameraModel::ideal_pixel(const Vec2& xy) const {
  return pixel_from_distorted(in_, xy);
}

Mat2 CameraModel::unproject_jacobian(const Vec2& xy) const {
  const DistortionTerms t = distortion_terms(in_, xy);
  return (pixel_from_distorted_jacobian(in_) * t.d_xy).inverse();
}

std::optional<Vec2> CameraModel::project(
    const Vec3& p_cam, Eigen::Matrix<double, 2, 3>* d_point_cam,
    Eigen::Matrix<double, 2, kNumIntrinsics>* d_intrinsics) const {
  const double z = p_cam.z();
  if (!(z > 0)) return std::nullopt;
  const Vec2 xy(p_cam.x() / z, p_cam.y() / z);
  const DistortionTerms t = distortion_terms(in_, xy);
  const Vec2 pixel = pixel_from_distorted(in_, t.distorted);

  if (d_point_cam) {
    Eigen::Matrix<double, 2, 3> d_xy_d_p;
    d_xy_d_p << 1 / z, 0, -xy.x() / z, 0, 1 / z, -xy.y() / z;
    *d_point_cam = pixel_from_distorted_jacobian(in_) * t.d_xy * d_xy_d_p;
  }
  if (d_intrinsics) {
    const double x = xy.x(), y = xy.y();
    // d(x', y') / d(k1, k2, p1, p2, k3, k4, k5, k6).
    Eigen::Matrix<double, 2, 8> d_dist;
    const double inv_den = 1 / t.den;
    const double radial_over_den = t.radial * inv_den;
    d_dist(0, 0) = x * t.r2 * inv_den;
    d_dist(1, 0) = y * t.r2 * inv_den;
    d_dist(0, 1) = x * t.r4 * inv_den;
    d_dist(1, 1) = y * t.r4 * inv_den;
    d_dist(0, 2) = 2 * x * y;
    d_dist(1, 2) = t.r2 + 2 * y * y;
    d_dist(0, 3) = t.r2 + 2 * x * x;
    d_dist(1, 3) = 2 * x * y;
    d_dist(0, 4) = x * t.r6 * inv_den;
    d_dist(1, 4) = y * t.r6 * inv_den;
    d_dist(0, 5) = -x * t.r2 * radial_over_den;
    d_dist(1, 5) = -y * t.r2 * radial_over_den;
    d_dist(0, 6) = -x * t.r4 * radial_over_den;
    d_dist(1, 6) = -y * t.r4 * radial_over_den;
    d_dist(0, 7) = -x * t.r6 * radial_over_den;
    d_dist(1, 7) = -y * t.r6 * radial_over_den;

    auto& J = *d_intrinsics;
    J.setZero();
    J(0, kFx) = t.distorted.x();
    J(1, kFy) = t.distorted.y();
    J(0, kCx) = 1;
    J(1, kCy) = 1;
    J(0, kSkew) = t.distorted.y();
    J.block<2, 8>(0, kK1) = pixel_from_distorted_jacobian(in_) * d_dist;
  }
  return pixel;
}

std::optional<Vec2> CameraModel::project_world(const geometry::Transform& T_c_w, const Vec3& p_w,
                                               ProjectionJacobians* jacobians) const {
  const Vec3 p_cam = T_c_w * p_w;
  if (!jacobians) return project(p_cam);
  auto pixel = project(p_cam, &jacobians->d_point_cam, &jacobians->d_intrinsics);
  if (!pixel) return std::nullopt;
  const Mat3& R_c_w = T_c_w.linear();
  jacobians->d_point_world = jacobians->d_point_cam * R_c_w;
  // Left perturbation (geometry::perturb_left): p_cam = Exp(dr) R p_w + t + dt, so
  // d p_cam / d dr = -[R p_w]x and d p_cam / d dt = I.
  jacobians->d_pose.leftCols<3>() = -jacobians->d_point_cam * geometry::skew(R_c_w * p_w);
  jacobians->d_pose.rightCols<3>() = jacobians->d_point_cam;
  return pixel;
}

std::optional<Vec2> project_body_point(const CalibratedCamera& camera,
                                       const geometry::Transform& T_w_b, const Vec3& p_b,
                                       Eigen::Matrix<double, 2, 6>* d_body_pose,
                                       ProjectionJacobians* jacobians) {
  const Vec3 Rp = T_w_b.linear() * p_b;
  const Vec3 p_w = Rp + T_w_b.translation();
  if (d_body_pose == nullptr && jacobians == nullptr)
    return camera.model.project_world(camera.T_c_w, p_w);
  ProjectionJacobians local;
  ProjectionJacobians& J = jacobians != nullptr ? *jacobians : local;
  const auto pixel = camera.model.project_world(camera.T_c_w, p_w, &J);
  if (!pixel) return std::nullopt;
  if (d_body_pose != nullptr) {
    // Left perturbation of the body pose: p_w = Exp(dr) R p_b + t + dt.
    d_body_pose->leftCols<3>() = -J.d_point_world * geometry::skew(Rp);
    d_body_pose->rightCols<3>() = J.d_point_world;
  }
  return pixel;
}

std::optional<Vec2> CameraModel::unproject(const Vec2& pixel, double tolerance_px,
                                           int max_iterations) const {
  if (!pixel.allFinite() || !(in_.fx != 0) || !(in_.fy != 0)) return std::nullopt;
  const Mat2 A = pixel_from_distorted_jacobian(in_);
  // Target distorted normalised point: invert the (affine) pixel map exactly.
  const double yd = (pixel.y() - in_.cy) / in_.fy;
  const Vec2 target((pixel.x() - in_.cx - in_.skew * yd) / in_.fx, yd);

  // Gauss-Newton (a Newton iteration here: the system is square) on distort(xy) = target,
  // started at the distorted point, with step halving so that the pixel residual never grows.
  Vec2 xy = target;
  DistortionTerms t = distortion_terms(in_, xy);
  double err_px = (A * (t.distorted - target)).norm();
  for (int it = 0; it < max_iterations && !(err_px <= tolerance_px); ++it) {
    const double det = t.d_xy.determinant();
    if (!std::isfinite(det) || std::abs(det) < 1e-12) return std::nullopt;
    const Vec2 step = t.d_xy.inverse() * (t.distorted - target);
    double scale = 1.0;
    bool improved = false;
    for (int halving = 0; halving < 30; ++halving, scale *= 0.5) {
      const Vec2 candidate = xy - scale * step;
      const DistortionTerms tc = distortion_terms(in_, candidate);
      const double err_c = (A * (tc.distorted - target)).norm();
      if (std::isfinite(err_c) && err_c < err_px) {
        xy = candidate;
        t = tc;
        err_px = err_c;
        improved = true;
        break;
      }
    }
    if (!improved) break;
  }
  if (!(err_px <= tolerance_px)) return std::nullopt;
  // A root is only the physical ray if the lens map is orientation-preserving there and the
  // radial factor has not flipped sign: beyond the fold of a strong barrel distortion another
  // (non-physical) pre-image exists, which we refuse rather than return.
  if (!(t.den > 0) || !(t.radial > 0) || !(t.d_xy.determinant() > 0)) return std::nullopt;
  return xy;
}

}  // namespace storetrack::camera
