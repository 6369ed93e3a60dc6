// Central projection with two lens models (docs/conventions.md, "Camera model").
//
// Rational Brown is OpenCV's (Bradski & Kaehler, "Learning OpenCV", ch. 11; D. C. Brown,
// "Decentering distortion of lenses", Photogrammetric Engineering 32(3), 1966), including the
// rational radial term k4..k6, so that parameters from cv::calibrateCamera apply unchanged.
// Kannala-Brandt is J. Kannala and S. S. Brandt, "A generic camera model and calibration method
// for conventional, wide-angle, and fish-eye lenses", IEEE PAMI 28(8), 2006, in the four-term
// form of OpenCV's cv::fisheye (whose parameters apply unchanged, skew in pixels).
// All Jacobians are analytic and checked against central differences in
// tests/common/camera/test_camera_model.cpp.
#include "storetrack/camera/camera_model.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace storetrack::camera {

using geometry::Mat2;
using geometry::Mat3;
using geometry::Vec2;
using geometry::Vec3;

namespace {

// Indices 0..12 into the packed intrinsic vector (camera_model.hpp); all named, some unused (an
// enum, so clang's -Wunused-const-variable does not object).
enum IntrinsicIndex : int { kFx, kFy, kCx, kCy, kSkew, kK1, kK2, kP1, kP2, kK3, kK4, kK5, kK6 };

using LensCoefficientJacobian = Eigen::Matrix<double, 2, 8>;

/// Everything of the distortion map at one normalised point, shared by distort(), unproject()
/// and the intrinsic Jacobian.
struct DistortionTerms {
  Vec2 distorted;
  Mat2 d_xy;
  /// The point is on the physical branch of the lens map (not beyond its fold), where an
  /// unproject root is the ray itself.
  bool physical;
};

DistortionTerms rational_brown_terms(const Intrinsics& in, const Vec2& xy,
                                     LensCoefficientJacobian* d_coefficients) {
  const auto& d = in.dist;
  const double k1 = d[0], k2 = d[1], p1 = d[2], p2 = d[3], k3 = d[4], k4 = d[5], k5 = d[6],
               k6 = d[7];
  const double x = xy.x(), y = xy.y();
  DistortionTerms t{};
  const double r2 = x * x + y * y, r4 = r2 * r2, r6 = r4 * r2;
  const double num = 1 + k1 * r2 + k2 * r4 + k3 * r6;
  const double den = 1 + k4 * r2 + k5 * r4 + k6 * r6;
  const double radial = num / den;
  t.distorted.x() = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x);
  t.distorted.y() = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y;

  // d radial / d r2 by the quotient rule.
  const double d_num = k1 + 2 * k2 * r2 + 3 * k3 * r4;
  const double d_den = k4 + 2 * k5 * r2 + 3 * k6 * r4;
  const double d_radial = (d_num * den - num * d_den) / (den * den);
  t.d_xy(0, 0) = radial + 2 * x * x * d_radial + 2 * p1 * y + 6 * p2 * x;
  t.d_xy(0, 1) = 2 * x * y * d_radial + 2 * p1 * x + 2 * p2 * y;
  t.d_xy(1, 0) = 2 * x * y * d_radial + 2 * p1 * x + 2 * p2 * y;
  t.d_xy(1, 1) = radial + 2 * y * y * d_radial + 6 * p1 * y + 2 * p2 * x;
  // Beyond the fold of a strong barrel distortion another (non-physical) pre-image exists.
  t.physical = den > 0 && radial > 0 && t.d_xy.determinant() > 0;

  if (d_coefficients) {
    // d(x', y') / d(k1, k2, p1, p2, k3, k4, k5, k6).
    auto& D = *d_coefficients;
    const double inv_den = 1 / den;
    const double radial_over_den = radial * inv_den;
    D(0, 0) = x * r2 * inv_den;
    D(1, 0) = y * r2 * inv_den;
    D(0, 1) = x * r4 * inv_den;
    D(1, 1) = y * r4 * inv_den;
    D(0, 2) = 2 * x * y;
    D(1, 2) = r2 + 2 * y * y;
    D(0, 3) = r2 + 2 * x * x;
    D(1, 3) = 2 * x * y;
    D(0, 4) = x * r6 * inv_den;
    D(1, 4) = y * r6 * inv_den;
    D(0, 5) = -x * r2 * radial_over_den;
    D(1, 5) = -y * r2 * radial_over_den;
    D(0, 6) = -x * r4 * radial_over_den;
    D(1, 6) = -y * r4 * radial_over_den;
    D(0, 7) = -x * r6 * radial_over_den;
    D(1, 7) = -y * r6 * radial_over_den;
  }
  return t;
}

/// Kannala-Brandt theta_d(theta) and its derivative d theta_d / d theta.
struct KannalaBrandtRadius {
  double theta_d, d_theta_d;
};

KannalaBrandtRadius kannala_brandt_radius(const Intrinsics& in, double theta) {
  const auto& k = in.dist;
  const double t2 = theta * theta;
  const double poly = 1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])));
  const double d_poly = 1 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])));
  return {theta * poly, d_poly};
}

/// theta_d increases on [0, theta]: the map is one-to-one there, so a root is the ray. Checked
/// on a grid of 64 points (the derivative is a quartic in theta^2: few sign changes).
bool kannala_brandt_monotonic_up_to(const Intrinsics& in, double theta) {
  constexpr int kSamples = 64;
  for (int i = 1; i <= kSamples; ++i)
    if (!(kannala_brandt_radius(in, theta * i / kSamples).d_theta_d > 0)) return false;
  return true;
}

// Below this normalised radius the ratios theta/r and theta_d/r use their Taylor series (the
// closed forms divide 0 by 0 at r = 0); the truncation error is O(r^4) < 1e-28.
constexpr double kSmallRadius = 1e-7;

DistortionTerms kannala_brandt_terms(const Intrinsics& in, const Vec2& xy,
                                     LensCoefficientJacobian* d_coefficients) {
  const double r2 = xy.squaredNorm(), r = std::sqrt(r2);
  const double theta = std::atan(r);
  const KannalaBrandtRadius radius = kannala_brandt_radius(in, theta);
  const double k1 = in.dist[0];
  // x' = xy g(r), g = theta_d / r; d x' / d xy = g I + (g'(r) / r) xy xy^T.
  double g, dg_over_r, theta_over_r;
  if (r < kSmallRadius) {
    g = 1 + (k1 - 1.0 / 3.0) * r2;
    dg_over_r = 2 * (k1 - 1.0 / 3.0);
    theta_over_r = 1 - r2 / 3;
  } else {
    g = radius.theta_d / r;
    const double d_theta_d_dr = radius.d_theta_d / (1 + r2);
    dg_over_r = (d_theta_d_dr * r - radius.theta_d) / (r2 * r);
    theta_over_r = theta / r;
  }
  DistortionTerms t{};
  t.distorted = g * xy;
  t.d_xy = g * Mat2::Identity() + dg_over_r * xy * xy.transpose();
  // The full check (monotonic on [0, theta]) is unproject's; this one is cheap.
  t.physical = radius.d_theta_d > 0 && g > 0;
  if (d_coefficients) {
    // d x' / d k_i = xy theta^(2i+1) / r.
    d_coefficients->setZero();
    double power = theta_over_r;  // theta^(2i+1) / r for i = 0
    for (int i = 0; i < 4; ++i) {
      power *= theta * theta;
      d_coefficients->col(i) = power * xy;
    }
  }
  return t;
}

DistortionTerms distortion_terms(const Intrinsics& in, const Vec2& xy,
                                 LensCoefficientJacobian* d_coefficients = nullptr) {
  return in.lens_model == LensModel::kKannalaBrandt ? kannala_brandt_terms(in, xy, d_coefficients)
                                                    : rational_brown_terms(in, xy, d_coefficients);
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

/// Kannala-Brandt off the axis by 45 degrees or more, from the 3-D point itself (the normalised
/// point x/z diverges at 90 degrees; the lens does not): x' = theta_d(theta) (X, Y) / rho with
/// theta = atan2(rho, Z), rho = |(X, Y)|, so rays beyond 90 degrees project too. Jacobians
/// d x' / d p_cam and d x' / d k.
Vec2 kannala_brandt_wide(const Intrinsics& in, const Vec3& p, Eigen::Matrix<double, 2, 3>* d_point,
                         LensCoefficientJacobian* d_coefficients) {
  const double rho2 = p.head<2>().squaredNorm(), rho = std::sqrt(rho2);
  const double range2 = rho2 + p.z() * p.z();
  const double theta = std::atan2(rho, p.z());
  const KannalaBrandtRadius radius = kannala_brandt_radius(in, theta);
  const Vec2 direction = p.head<2>() / rho;
  if (d_point) {
    Eigen::RowVector3d d_theta;
    d_theta << p.z() * direction.x() / range2, p.z() * direction.y() / range2, -rho / range2;
    Eigen::Matrix<double, 2, 3> d_direction = Eigen::Matrix<double, 2, 3>::Zero();
    d_direction.leftCols<2>() = (Mat2::Identity() - direction * direction.transpose()) / rho;
    *d_point = radius.d_theta_d * direction * d_theta + radius.theta_d * d_direction;
  }
  if (d_coefficients) {
    d_coefficients->setZero();
    double power = theta;  // d theta_d / d k_i = theta^(2i+3)
    for (int i = 0; i < 4; ++i) {
      power *= theta * theta;
      d_coefficients->col(i) = power * direction;
    }
  }
  return radius.theta_d * direction;
}

/// The distorted normalised point x' of a camera-frame point, with d x' / d p_cam and
/// d x' / d(lens coefficients) when asked. nullopt: not finite, or behind the camera (rational
/// Brown: Z <= 0; Kannala-Brandt: on the negative Z axis).
std::optional<Vec2> distorted_point(const Intrinsics& in, const Vec3& p_cam,
                                    Eigen::Matrix<double, 2, 3>* d_point,
                                    LensCoefficientJacobian* d_coefficients) {
  if (!p_cam.allFinite()) return std::nullopt;
  const double z = p_cam.z();
  if (in.lens_model == LensModel::kKannalaBrandt && !(z > p_cam.head<2>().norm())) {
    if (!(p_cam.head<2>().norm() > 0)) return std::nullopt;
    return kannala_brandt_wide(in, p_cam, d_point, d_coefficients);
  }
  if (!(z > 0)) return std::nullopt;
  const Vec2 xy(p_cam.x() / z, p_cam.y() / z);
  const DistortionTerms t = distortion_terms(in, xy, d_coefficients);
  if (d_point) {
    Eigen::Matrix<double, 2, 3> d_xy_d_p;
    d_xy_d_p << 1 / z, 0, -xy.x() / z, 0, 1 / z, -xy.y() / z;
    *d_point = t.d_xy * d_xy_d_p;
  }
  return t.distorted;
}

/// Kannala-Brandt inverse: Newton on theta_d(theta) = |target| (one unknown, the map being
/// radial), started at theta = theta_d. Its domain: theta in [0, 90 deg) with theta_d increasing
/// on [0, theta] (then the root is unique and is the ray); outside it, nullopt.
std::optional<Vec2> unproject_kannala_brandt(const Intrinsics& in, const Vec2& target,
                                             double tolerance_px, int max_iterations) {
  const double target_theta_d = target.norm();
  if (target_theta_d == 0) return Vec2::Zero();
  constexpr double kRightAngle = std::numbers::pi / 2;
  double theta = std::min(target_theta_d, 0.5 * kRightAngle);
  for (int it = 0; it < max_iterations; ++it) {
    const KannalaBrandtRadius radius = kannala_brandt_radius(in, theta);
    if (!(radius.d_theta_d > 0)) return std::nullopt;
    const double step = (radius.theta_d - target_theta_d) / radius.d_theta_d;
    double next = theta - step;
    // Stay inside [0, 90 deg): halve the distance to the violated end instead.
    if (next < 0) next = 0.5 * theta;
    if (next >= kRightAngle) next = 0.5 * (theta + kRightAngle);
    const bool converged = std::abs(next - theta) <= 1e-15 * kRightAngle;
    theta = next;
    if (converged) break;
  }
  if (!(theta < kRightAngle) || !kannala_brandt_monotonic_up_to(in, theta)) return std::nullopt;
  const Vec2 xy = target * (std::tan(theta) / target_theta_d);
  const DistortionTerms t = distortion_terms(in, xy);
  const double err_px = (pixel_from_distorted_jacobian(in) * (t.distorted - target)).norm();
  if (!(err_px <= tolerance_px) || !t.physical) return std::nullopt;
  return xy;
}

}  // namespace

IntrinsicVector pack(const Intrinsics& in) {
  IntrinsicVector v;
  v << in.fx, in.fy, in.cx, in.cy, in.skew, in.dist[0], in.dist[1], in.dist[2], in.dist[3],
      in.dist[4], in.dist[5], in.dist[6], in.dist[7];
  return v;
}

int lens_coefficient_count(LensModel model) {
  return model == LensModel::kKannalaBrandt ? 4 : 8;
}

const char* lens_model_name(LensModel model) {
  return model == LensModel::kKannalaBrandt ? "kannala-brandt" : "rational-brown";
}

std::optional<LensModel> lens_model_from_name(std::string_view name) {
  for (const LensModel model : {LensModel::kRationalBrown, LensModel::kKannalaBrandt})
    if (name == lens_model_name(model)) return model;
  return std::nullopt;
}

Intrinsics unpack(const IntrinsicVector& v, int width, int height, LensModel lens_model) {
  Intrinsics in;
  in.lens_model = lens_model;
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
  LensCoefficientJacobian d_coefficients;
  const auto distorted =
      distorted_point(in_, p_cam, d_point_cam, d_intrinsics ? &d_coefficients : nullptr);
  if (!distorted) return std::nullopt;
  const Mat2 A = pixel_from_distorted_jacobian(in_);
  if (d_point_cam) *d_point_cam = A * *d_point_cam;
  if (d_intrinsics) {
    auto& J = *d_intrinsics;
    J.setZero();
    J(0, kFx) = distorted->x();
    J(1, kFy) = distorted->y();
    J(0, kCx) = 1;
    J(1, kCy) = 1;
    J(0, kSkew) = distorted->y();
    J.block<2, 8>(0, kK1) = A * d_coefficients;
  }
  return pixel_from_distorted(in_, *distorted);
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
  if (in_.lens_model == LensModel::kKannalaBrandt)
    return unproject_kannala_brandt(in_, target, tolerance_px, max_iterations);

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
  // A root beyond the fold of the lens map is not the ray: refused rather than returned.
  if (!t.physical) return std::nullopt;
  return xy;
}

}  // namespace storetrack::camera
