// Camera model: analytic Jacobians vs central finite differences, unproject/project round trip
// over the whole image (also under strong distortion), and non-convergence reporting.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "storetrack/camera/camera_model.hpp"

namespace storetrack::camera {
namespace {

using geometry::Mat2;
using geometry::Vec2;
using geometry::Vec3;
using geometry::Vec6;

/// A realistic 1920x1024 camera with moderate distortion of every kind, rational terms included.
Intrinsics typical_intrinsics() {
  Intrinsics in;
  in.fx = 1450.3;
  in.fy = 1448.7;
  in.cx = 962.1;
  in.cy = 508.4;
  in.skew = 0.8;
  in.dist = {-0.21, 0.09, 4e-4, -3e-4, -0.02, 0.05, -0.01, 0.004};
  return in;
}

/// Random intrinsics around typical values (OpenCV-like ranges, including strong distortion).
Intrinsics random_intrinsics(std::mt19937_64& rng, bool rational, bool with_skew) {
  std::uniform_real_distribution<double> u(-1, 1);
  Intrinsics in;
  in.fx = 1200 + 400 * u(rng);
  in.fy = in.fx * (1 + 0.01 * u(rng));
  in.cx = 959.5 + 30 * u(rng);
  in.cy = 511.5 + 30 * u(rng);
  in.skew = with_skew ? 2 * u(rng) : 0;
  in.dist = {0.3 * u(rng), 0.1 * u(rng), 1e-3 * u(rng), 1e-3 * u(rng), 0.05 * u(rng), 0, 0, 0};
  if (rational) {
    in.dist[5] = 0.1 * u(rng);
    in.dist[6] = 0.02 * u(rng);
    in.dist[7] = 0.005 * u(rng);
  }
  return in;
}

/// A camera-frame point that projects (ideally) inside the image of `in`, at depth 2..20 m.
Vec3 random_point_in_view(std::mt19937_64& rng, const Intrinsics& in) {
  std::uniform_real_distribution<double> uu(0, in.width - 1), vv(0, in.height - 1), zz(2, 20);
  const double z = zz(rng);
  return {(uu(rng) - in.cx) / in.fx * z, (vv(rng) - in.cy) / in.fy * z, z};
}

// geometry::left_difference inverts perturb_left (up to rotations of pi, where Log is ambiguous).
/// Central-difference Jacobian of project(p) w.r.t. the packed intrinsics: steps h_k px for
/// K (k < 5) and `distortion_step` for the lens coefficients.
Eigen::Matrix<double, 2, kNumIntrinsics> numeric_intrinsic_jacobian(const Intrinsics& in,
                                                                    const Vec3& p,
                                                                    double distortion_step) {
  Eigen::Matrix<double, 2, kNumIntrinsics> J;
  const IntrinsicVector v = pack(in);
  for (int k = 0; k < kNumIntrinsics; ++k) {
    const double h = k < 5 ? 1e-4 : distortion_step;
    IntrinsicVector a = v, b = v;
    a[k] += h;
    b[k] -= h;
    const Vec2 pa = *CameraModel(unpack(a, in.width, in.height, in.lens_model)).project(p);
    const Vec2 pb = *CameraModel(unpack(b, in.width, in.height, in.lens_model)).project(p);
    J.col(k) = (pa - pb) / (2 * h);
  }
  return J;
}

TEST(Geometry, LeftDifferenceInvertsPerturbLeft) {
  const geometry::Transform T = geometry::make_transform(Vec3(0.3, -1.2, 2.0), Vec3(1, 2, 3));
  for (const double scale : {1e-6, 1e-2, 1.0, 3.0}) {
    geometry::Vec6 delta;
    delta << 0.4, -0.7, 0.5, 0.1, -0.2, 0.3;
    delta.head<3>() *= scale / delta.head<3>().norm();  // rotation angle = scale < pi
    const geometry::Vec6 back = geometry::left_difference(geometry::perturb_left(T, delta), T);
    EXPECT_LT((back - delta).norm(), 1e-12) << scale;
  }
}

TEST(CameraModel, PackUnpackRoundTrip) {
  const Intrinsics in = typical_intrinsics();
  const Intrinsics back = unpack(pack(in), in.width, in.height, in.lens_model);
  EXPECT_EQ(pack(back), pack(in));
  EXPECT_EQ(back.width, in.width);
  EXPECT_EQ(back.height, in.height);
}

TEST(CameraModel, PrincipalPointOnAxis) {
  const CameraModel cam(typical_intrinsics());
  const auto px = cam.project(Vec3(0, 0, 5));
  ASSERT_TRUE(px);
  EXPECT_NEAR(px->x(), cam.intrinsics().cx, 1e-12);
  EXPECT_NEAR(px->y(), cam.intrinsics().cy, 1e-12);
}

TEST(CameraModel, BehindCameraIsRejected) {
  const CameraModel cam(typical_intrinsics());
  EXPECT_FALSE(cam.project(Vec3(0.1, 0.2, 0)));
  EXPECT_FALSE(cam.project(Vec3(0.1, 0.2, -1)));
  EXPECT_FALSE(cam.project(Vec3(0.1, 0.2, std::nan(""))));
}

TEST(CameraModel, DistortJacobianMatchesFiniteDifferences) {
  std::mt19937_64 rng(1);
  for (int trial = 0; trial < 200; ++trial) {
    const CameraModel cam(random_intrinsics(rng, trial % 2 == 0, true));
    const Vec3 p = random_point_in_view(rng, cam.intrinsics());
    const Vec2 xy = p.head<2>() / p.z();
    Mat2 J;
    cam.distort(xy, &J);
    const double h = 1e-6;
    for (int k = 0; k < 2; ++k) {
      Vec2 a = xy, b = xy;
      a[k] += h;
      b[k] -= h;
      const Vec2 num = (cam.distort(a) - cam.distort(b)) / (2 * h);
      EXPECT_NEAR((J.col(k) - num).norm(), 0, 1e-7) << "trial " << trial << " col " << k;
    }
  }
}

TEST(CameraModel, PointJacobianMatchesFiniteDifferences) {
  std::mt19937_64 rng(2);
  for (int trial = 0; trial < 200; ++trial) {
    const CameraModel cam(random_intrinsics(rng, trial % 2 == 0, true));
    const Vec3 p = random_point_in_view(rng, cam.intrinsics());
    Eigen::Matrix<double, 2, 3> J;
    ASSERT_TRUE(cam.project(p, &J));
    const double h = 1e-5;  // m
    for (int k = 0; k < 3; ++k) {
      Vec3 a = p, b = p;
      a[k] += h;
      b[k] -= h;
      const Vec2 num = (*cam.project(a) - *cam.project(b)) / (2 * h);
      // Relative to the column size (hundreds of px/m): FD truncation error is ~h^2.
      EXPECT_LT((J.col(k) - num).norm(), 1e-6 * (1 + num.norm())) << "trial " << trial;
    }
  }
}

TEST(CameraModel, IntrinsicJacobianMatchesFiniteDifferences) {
  std::mt19937_64 rng(3);
  for (int trial = 0; trial < 200; ++trial) {
    const Intrinsics in = random_intrinsics(rng, trial % 2 == 0, true);
    const CameraModel cam(in);
    const Vec3 p = random_point_in_view(rng, in);
    Eigen::Matrix<double, 2, kNumIntrinsics> J;
    ASSERT_TRUE(cam.project(p, nullptr, &J));
    const Eigen::Matrix<double, 2, kNumIntrinsics> numeric =
        numeric_intrinsic_jacobian(in, p, 1e-5);
    for (int k = 0; k < kNumIntrinsics; ++k) {
      const Vec2 num = numeric.col(k);
      EXPECT_LT((J.col(k) - num).norm(), 1e-6 * (1 + num.norm()))
          << "trial " << trial << " parameter " << k;
    }
  }
}

TEST(CameraModel, WorldAndPoseJacobiansMatchFiniteDifferences) {
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int trial = 0; trial < 200; ++trial) {
    const Intrinsics in = random_intrinsics(rng, trial % 2 == 0, true);
    const CameraModel cam(in);
    const geometry::Transform T_c_w =
        geometry::make_transform(Vec3(u(rng), u(rng), u(rng)), Vec3(u(rng), u(rng), u(rng)) * 3);
    const Vec3 p_cam = random_point_in_view(rng, in);
    const Vec3 p_w = T_c_w.inverse() * p_cam;
    ProjectionJacobians J;
    const auto px = cam.project_world(T_c_w, p_w, &J);
    ASSERT_TRUE(px);
    EXPECT_NEAR((*px - *cam.project(p_cam)).norm(), 0, 1e-9);

    // Consistency with the camera-frame projection.
    Eigen::Matrix<double, 2, 3> Jc;
    Eigen::Matrix<double, 2, kNumIntrinsics> Ji;
    cam.project(p_cam, &Jc, &Ji);
    EXPECT_LT((J.d_point_cam - Jc).norm(), 1e-9 * Jc.norm());
    EXPECT_LT((J.d_intrinsics - Ji).norm(), 1e-9 * Ji.norm());

    for (int k = 0; k < 3; ++k) {
      const double h = 1e-5;
      Vec3 a = p_w, b = p_w;
      a[k] += h;
      b[k] -= h;
      const Vec2 num = (*cam.project_world(T_c_w, a) - *cam.project_world(T_c_w, b)) / (2 * h);
      EXPECT_LT((J.d_point_world.col(k) - num).norm(), 1e-6 * (1 + num.norm()));
    }
    for (int k = 0; k < 6; ++k) {
      const double h = k < 3 ? 1e-6 : 1e-5;  // rad, m
      Vec6 d = Vec6::Zero();
      d[k] = h;
      const Vec2 pa = *cam.project_world(geometry::perturb_left(T_c_w, d), p_w);
      const Vec2 pb = *cam.project_world(geometry::perturb_left(T_c_w, -d), p_w);
      const Vec2 num = (pa - pb) / (2 * h);
      EXPECT_LT((J.d_pose.col(k) - num).norm(), 1e-5 * (1 + num.norm()))
          << "trial " << trial << " pose component " << k;
    }
  }
}

TEST(CameraModel, BodyPointProjectionJacobianMatchesFiniteDifferences) {
  // The single-view measurement of a mark (host/match's pose filter, host/pipeline's
  // resection): d pixel / d(left perturbation of the body pose T_w_b), by central differences
  // of perturb_left, and the pixel itself against projecting T_w_b p_b directly.
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int trial = 0; trial < 200; ++trial) {
    CalibratedCamera camera;
    camera.model = CameraModel(random_intrinsics(rng, trial % 2 == 0, true));
    camera.T_c_w =
        geometry::make_transform(Vec3(u(rng), u(rng), u(rng)), Vec3(u(rng), u(rng), u(rng)) * 3);
    const Vec3 p_w = camera.T_c_w.inverse() * random_point_in_view(rng, camera.model.intrinsics());
    const Vec3 p_b = Vec3(u(rng), u(rng), u(rng)) * 0.8;  // a mark up to ~1.4 m off the origin
    geometry::Transform T_w_b =
        geometry::make_transform(Vec3(u(rng), u(rng), u(rng)), Vec3::Zero());
    T_w_b.translation() = p_w - T_w_b.linear() * p_b;  // the mark lands on the in-view point
    Eigen::Matrix<double, 2, 6> H;
    ProjectionJacobians J;
    const auto px = project_body_point(camera, T_w_b, p_b, &H, &J);
    ASSERT_TRUE(px);
    EXPECT_LT((*px - *camera.model.project_world(camera.T_c_w, p_w)).norm(), 1e-9);
    EXPECT_LT((*project_body_point(camera, T_w_b, p_b) - *px).norm(), 1e-12);
    for (int k = 0; k < 6; ++k) {
      const double h = k < 3 ? 1e-6 : 1e-5;  // rad, m
      Vec6 d = Vec6::Zero();
      d[k] = h;
      const Vec2 pa = *project_body_point(camera, geometry::perturb_left(T_w_b, d), p_b);
      const Vec2 pb = *project_body_point(camera, geometry::perturb_left(T_w_b, -d), p_b);
      const Vec2 num = (pa - pb) / (2 * h);
      EXPECT_LT((H.col(k) - num).norm(), 1e-5 * (1 + num.norm()))
          << "trial " << trial << " pose component " << k;
    }
  }
  // Behind the camera: no pixel.
  CalibratedCamera camera;
  camera.model = CameraModel(typical_intrinsics());
  EXPECT_FALSE(project_body_point(camera, geometry::Transform::Identity(), Vec3(0, 0, -1)));
}

TEST(CameraModel, UnprojectJacobianMatchesFiniteDifferences) {
  std::mt19937_64 rng(5);
  for (int trial = 0; trial < 100; ++trial) {
    const CameraModel cam(random_intrinsics(rng, trial % 2 == 0, true));
    const auto px = cam.project(random_point_in_view(rng, cam.intrinsics()));
    ASSERT_TRUE(px);
    const auto xy = cam.unproject(*px, 1e-10);
    ASSERT_TRUE(xy);
    const Mat2 J = cam.unproject_jacobian(*xy);
    const double h = 1e-3;  // px
    for (int k = 0; k < 2; ++k) {
      Vec2 a = *px, b = *px;
      a[k] += h;
      b[k] -= h;
      const auto xa = cam.unproject(a, 1e-11), xb = cam.unproject(b, 1e-11);
      ASSERT_TRUE(xa && xb);
      const Vec2 num = (*xa - *xb) / (2 * h);
      EXPECT_LT((J.col(k) - num).norm(), 1e-6 * num.norm());
    }
  }
}

/// True when the lens map is physically valid over the image: along rays out to well beyond
/// the image corners the radial factor stays positive and the map orientation-preserving, and
/// the distorted image of that radius lies outside the image (so every pixel has a pre-image).
bool lens_valid_over_image(const Intrinsics& in) {
  const CameraModel cam(in);
  Intrinsics pin = in;
  pin.dist = {};
  double corner_r = 0;
  for (const Vec2& c : {Vec2(-0.5, -0.5), Vec2(in.width - 0.5, -0.5), Vec2(-0.5, in.height - 0.5),
                        Vec2(in.width - 0.5, in.height - 0.5)})
    corner_r = std::max(corner_r, CameraModel(pin).unproject(c)->norm());
  for (int a = 0; a < 72; ++a) {
    const Vec2 dir(std::cos(a * M_PI / 36), std::sin(a * M_PI / 36));
    double s = 0;
    for (; s <= 3 * corner_r; s += corner_r / 200) {
      Mat2 J;
      const Vec2 d = cam.distort(s * dir, &J);
      if (!(J.determinant() > 0) || !(d.dot(dir) > 0 || s == 0)) return false;
      if (d.norm() > 1.05 * corner_r) break;
    }
    if (s > 3 * corner_r) return false;
  }
  return true;
}

/// Checks that every pixel of a grid covering the whole image (edges and corners included)
/// unprojects, and that projecting the ray returns the pixel and unprojecting the projection of
/// the ray returns the ray.
void expect_round_trip_over_image(const Intrinsics& in, double tolerance_px) {
  const CameraModel cam(in);
  int count = 0;
  for (double v = -0.5; v <= in.height - 0.5; v += (in.height - 1.0) / 40) {
    for (double u = -0.5; u <= in.width - 0.5; u += (in.width - 1.0) / 60) {
      const Vec2 px(u, v);
      const auto xy = cam.unproject(px, tolerance_px);
      ASSERT_TRUE(xy) << "pixel " << u << ", " << v;
      const auto back = cam.project(Vec3(xy->x(), xy->y(), 1) * 7.3);
      ASSERT_TRUE(back);
      EXPECT_LT((*back - px).norm(), tolerance_px) << "pixel " << u << ", " << v;
      // unproject(project(p)): the ray of a 3-D point is recovered.
      const Vec3 p = Vec3(xy->x(), xy->y(), 1) * 3.1;
      const auto xy2 = cam.unproject(*cam.project(p), tolerance_px);
      ASSERT_TRUE(xy2);
      // A pixel error of tol maps to tol |d xy / d pixel| in normalised coordinates.
      EXPECT_LT((*xy2 - p.head<2>() / p.z()).norm(),
                2 * tolerance_px * cam.unproject_jacobian(*xy2).norm());
      ++count;
    }
  }
  EXPECT_GT(count, 2000);
}

TEST(CameraModel, RoundTripOverWholeImageTypical) {
  expect_round_trip_over_image(typical_intrinsics(), 1e-9);
}

TEST(CameraModel, RoundTripOverWholeImageStrongBarrel) {
  // Wide-angle lens: image corners pulled in by ~360 px (r_d = r (1 - 0.3 r^2 + 0.08 r^4)).
  Intrinsics in;
  in.fx = in.fy = 1000;
  in.dist = {-0.3, 0.08, 1e-3, -1e-3, 0, 0, 0, 0};
  ASSERT_TRUE(lens_valid_over_image(in));
  expect_round_trip_over_image(in, 1e-9);
}

TEST(CameraModel, RoundTripOverWholeImageStrongPincushionRational) {
  Intrinsics in;
  in.fx = in.fy = 900;
  in.skew = 1.5;
  in.dist = {0.4, 0.2, -2e-3, 1e-3, 0.05, 0.3, 0.02, 0.01};
  ASSERT_TRUE(lens_valid_over_image(in));
  expect_round_trip_over_image(in, 1e-9);
}

TEST(CameraModel, RoundTripRandomParameterSets) {
  // Random lenses, kept only when physically valid over the image (a lens whose map folds
  // inside the field of view cannot have produced the image corners).
  std::mt19937_64 rng(6);
  int tested = 0;
  for (int trial = 0; tested < 40 && trial < 1000; ++trial) {
    const Intrinsics in = random_intrinsics(rng, trial % 2 == 0, trial % 3 == 0);
    if (!lens_valid_over_image(in)) continue;
    expect_round_trip_over_image(in, 1e-8);
    ++tested;
  }
  EXPECT_EQ(tested, 40);
}

TEST(CameraModel, UnprojectReportsNonConvergence) {
  // Barrel distortion r_d = r (1 + k1 r^2) folds at r = 1/sqrt(3 |k1|), where r_d peaks at
  // 2/(3 sqrt(3 |k1|)): pixels beyond that radius have no physical pre-image.
  Intrinsics in;
  in.fx = in.fy = 1000;
  in.dist = {-0.5, 0, 0, 0, 0, 0, 0, 0};
  const CameraModel cam(in);
  const double rd_max = 2 / (3 * std::sqrt(1.5));
  EXPECT_TRUE(cam.unproject(Vec2(in.cx + 0.95 * rd_max * in.fx, in.cy)));
  EXPECT_FALSE(cam.unproject(Vec2(in.cx + 1.05 * rd_max * in.fx, in.cy)));
  EXPECT_FALSE(cam.unproject(Vec2(in.cx + 3 * rd_max * in.fx, in.cy + 100)));
  // Not enough iterations for the requested tolerance -> reported, not returned.
  const Vec2 corner(0, 0);
  Intrinsics strong = in;
  strong.dist[0] = -0.1;  // folds at r = 1.83, beyond the corners (r_d = 1.09)
  const CameraModel cam2(strong);
  EXPECT_TRUE(cam2.unproject(corner, 1e-9, 50));
  EXPECT_FALSE(cam2.unproject(corner, 1e-9, 1));
  // Non-finite input.
  EXPECT_FALSE(cam.unproject(Vec2(std::nan(""), 3)));
  EXPECT_FALSE(cam.unproject(Vec2(INFINITY, 3)));
}

// ---- Kannala-Brandt (equidistant fisheye) ----

/// A 190-degree-class fisheye on a 1920x1024 sensor: f = 330 px puts theta = 90 deg at
/// theta_d f ~ 520 px from the centre (the image circle's edge at the short side).
Intrinsics fisheye_intrinsics() {
  Intrinsics in;
  in.lens_model = LensModel::kKannalaBrandt;
  in.fx = 331.2;
  in.fy = 330.4;
  in.cx = 961.3;
  in.cy = 509.8;
  in.skew = 0.4;
  in.dist = {0.021, -0.008, 0.0031, -0.0007, 0, 0, 0, 0};
  return in;
}

Intrinsics random_fisheye_intrinsics(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  Intrinsics in = fisheye_intrinsics();
  in.fx = 330 + 60 * u(rng);
  in.fy = in.fx * (1 + 0.01 * u(rng));
  in.cx += 20 * u(rng);
  in.cy += 20 * u(rng);
  in.skew = u(rng);
  in.dist = {0.05 * u(rng), 0.02 * u(rng), 0.005 * u(rng), 0.001 * u(rng), 0, 0, 0, 0};
  return in;
}

/// d theta_d / d theta > 0 on [0, theta_max] (closed form, sampled every 0.01 deg): the lens
/// map is one-to-one there, so every projection in that cone has its ray as the only pre-image.
bool fisheye_monotonic_to(const Intrinsics& in, double theta_max) {
  const auto& k = in.dist;
  for (double theta = 0; theta <= theta_max; theta += 0.01 * M_PI / 180) {
    const double t2 = theta * theta;
    if (!(1 + 3 * k[0] * t2 + 5 * k[1] * t2 * t2 + 7 * k[2] * t2 * t2 * t2 +
              9 * k[3] * t2 * t2 * t2 * t2 >
          0))
      return false;
  }
  return true;
}

/// A camera-frame point at angle theta from the axis, azimuth phi, distance 0.5..20 m.
Vec3 point_at_angle(double theta, double phi, double distance) {
  return distance *
         Vec3(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
}

TEST(KannalaBrandt, ProjectionIsTheClosedForm) {
  // theta_d = theta (1 + k1 theta^2 + ...), pixel = K (theta_d cos phi, theta_d sin phi).
  const Intrinsics in = fisheye_intrinsics();
  const CameraModel cam(in);
  // Beyond 90 degrees too: a fisheye sees behind its image plane (theta = atan2(rho, Z)).
  for (const double theta_deg :
       {0.0, 1e-9, 0.3, 10.0, 44.99, 45.0, 45.01, 80.0, 89.0, 89.9, 90.0, 100.0, 120.0}) {
    const double theta = theta_deg * M_PI / 180, phi = 0.7;
    const double t2 = theta * theta;
    const double theta_d = theta * (1 + in.dist[0] * t2 + in.dist[1] * t2 * t2 +
                                    in.dist[2] * t2 * t2 * t2 + in.dist[3] * t2 * t2 * t2 * t2);
    const Vec2 xd(theta_d * std::cos(phi), theta_d * std::sin(phi));
    const Vec2 expected(in.fx * xd.x() + in.skew * xd.y() + in.cx, in.fy * xd.y() + in.cy);
    const auto px = cam.project(point_at_angle(theta, phi, 3.7));
    ASSERT_TRUE(px) << theta_deg;
    EXPECT_LT((*px - expected).norm(), 1e-9) << theta_deg;
  }
  EXPECT_FALSE(cam.project(Vec3(0, 0, -2)));  // the negative axis: no azimuth
  EXPECT_FALSE(cam.project(Vec3(0.1, std::nan(""), 1)));
}

TEST(KannalaBrandt, JacobiansMatchFiniteDifferences) {
  // Point, intrinsic and distort() Jacobians against central differences.
  std::mt19937_64 rng(21);
  std::uniform_real_distribution<double> uu(0, 1);
  for (int trial = 0; trial < 300; ++trial) {
    const Intrinsics in = random_fisheye_intrinsics(rng);
    const CameraModel cam(in);
    // The axis (series branch), both sides of the 45-degree switch to the 3-D form, out to 120.
    const double theta = trial % 10 == 0 ? 1e-9 : 120.0 * M_PI / 180 * uu(rng);
    const Vec3 p = point_at_angle(theta, 2 * M_PI * uu(rng), 0.5 + 19.5 * uu(rng));
    Eigen::Matrix<double, 2, 3> Jp;
    Eigen::Matrix<double, 2, kNumIntrinsics> Ji;
    ASSERT_TRUE(cam.project(p, &Jp, &Ji));
    for (int k = 0; k < 3; ++k) {
      const double h = 1e-6 * p.norm();
      Vec3 a = p, b = p;
      a[k] += h;
      b[k] -= h;
      const Vec2 num = (*cam.project(a) - *cam.project(b)) / (2 * h);
      EXPECT_LT((Jp.col(k) - num).norm(), 1e-6 * (1 + num.norm()))
          << "trial " << trial << " theta " << theta << " point " << k;
    }
    const Eigen::Matrix<double, 2, kNumIntrinsics> numeric =
        numeric_intrinsic_jacobian(in, p, 1e-6);
    for (int k = 0; k < kNumIntrinsics; ++k) {
      const Vec2 num = numeric.col(k);
      EXPECT_LT((Ji.col(k) - num).norm(), 1e-6 * (1 + num.norm()))
          << "trial " << trial << " parameter " << k;
      if (k >= 9) {
        EXPECT_EQ(Ji.col(k).norm(), 0) << "unused coefficient " << k;
      }
    }
    if (!(p.z() > 0)) continue;  // distort() takes the normalised point (Z > 0)
    Mat2 Jd;
    const Vec2 xy = p.head<2>() / p.z();
    cam.distort(xy, &Jd);
    for (int k = 0; k < 2; ++k) {
      const double h = 1e-7 * (1 + xy.norm());
      Vec2 a = xy, b = xy;
      a[k] += h;
      b[k] -= h;
      const Vec2 num = (cam.distort(a) - cam.distort(b)) / (2 * h);
      EXPECT_LT((Jd.col(k) - num).norm(), 1e-6 * (1 + num.norm())) << "trial " << trial;
    }
  }
}

TEST(KannalaBrandt, RoundTripOutTo89Degrees) {
  // project -> unproject recovers the ray to 1e-9 rad and the pixel to 1e-9 px, from the axis
  // to 89 degrees (where the normalised radius tan(theta) is 57).
  std::mt19937_64 rng(22);
  std::uniform_real_distribution<double> uu(0, 1);
  double worst_rad = 0, worst_px = 0;
  for (int trial = 0; trial < 2000; ++trial) {
    Intrinsics in = fisheye_intrinsics();
    if (trial >= 1000) {
      do {  // lenses whose map folds inside 89 degrees cannot have made the image: redrawn
        in = random_fisheye_intrinsics(rng);
      } while (!fisheye_monotonic_to(in, 89.0 * M_PI / 180));
    }
    const CameraModel cam(in);
    const double theta = 89.0 * M_PI / 180 * (trial % 100 == 0 ? 1.0 : uu(rng));
    const Vec3 p = point_at_angle(theta, 2 * M_PI * uu(rng), 1 + 9 * uu(rng));
    const auto px = cam.project(p);
    ASSERT_TRUE(px);
    const auto xy = cam.unproject(*px, 1e-10);
    ASSERT_TRUE(xy) << "trial " << trial << " theta " << theta;
    const Vec3 ray = Vec3(xy->x(), xy->y(), 1).normalized();
    const double angle = std::atan2(ray.cross(p.normalized()).norm(), ray.dot(p.normalized()));
    const double px_error = (*cam.project(Vec3(xy->x(), xy->y(), 1)) - *px).norm();
    worst_rad = std::max(worst_rad, angle);
    worst_px = std::max(worst_px, px_error);
    EXPECT_LT(angle, 1e-9) << "trial " << trial << " theta " << theta;
    EXPECT_LT(px_error, 1e-9) << "trial " << trial << " theta " << theta;
  }
  RecordProperty("worst_rad", std::to_string(worst_rad));
  RecordProperty("worst_px", std::to_string(worst_px));
}

TEST(KannalaBrandt, UnprojectJacobianMatchesFiniteDifferences) {
  const CameraModel cam(fisheye_intrinsics());
  for (const double theta_deg : {0.5, 30.0, 60.0, 85.0}) {
    const auto px = cam.project(point_at_angle(theta_deg * M_PI / 180, 2.1, 4));
    const auto xy = cam.unproject(*px, 1e-10);
    ASSERT_TRUE(xy);
    const Mat2 J = cam.unproject_jacobian(*xy);
    for (int k = 0; k < 2; ++k) {
      const double h = 1e-3;  // px
      Vec2 a = *px, b = *px;
      a[k] += h;
      b[k] -= h;
      const Vec2 num = (*cam.unproject(a, 1e-11) - *cam.unproject(b, 1e-11)) / (2 * h);
      EXPECT_LT((J.col(k) - num).norm(), 1e-6 * num.norm()) << theta_deg;
    }
  }
}

TEST(KannalaBrandt, UnprojectRefusesOutsideItsDomain) {
  // Beyond the image circle of 90 degrees: no ray with Z > 0.
  Intrinsics in = fisheye_intrinsics();
  in.dist = {};
  const CameraModel equidistant(in);
  const double right_angle_px = M_PI / 2 * in.fy;
  EXPECT_TRUE(equidistant.unproject(Vec2(in.cx, in.cy + 0.999 * right_angle_px)));
  EXPECT_FALSE(equidistant.unproject(Vec2(in.cx, in.cy + 1.001 * right_angle_px)));
  EXPECT_FALSE(equidistant.unproject(Vec2(in.cx, in.cy + 3 * right_angle_px)));
  // theta_d = theta (1 - 0.3 theta^2) peaks at theta = 1/sqrt(0.9) = 1.054 rad (60 deg) at
  // theta_d = 0.703: beyond the fold the map is not one-to-one, refused; inside it, the ray.
  in.dist = {-0.3, 0, 0, 0, 0, 0, 0, 0};
  const CameraModel folding(in);
  const double fold = 1 / std::sqrt(0.9), peak = fold * (1 - 0.3 * fold * fold);
  const auto inside = folding.unproject(Vec2(in.cx + 0.95 * peak * in.fx, in.cy));
  ASSERT_TRUE(inside);
  EXPECT_LT(std::atan(inside->norm()), fold);
  EXPECT_FALSE(folding.unproject(Vec2(in.cx + 1.01 * peak * in.fx, in.cy)));
  EXPECT_FALSE(folding.unproject(Vec2(std::nan(""), in.cy)));
}

TEST(KannalaBrandt, ModelNamesRoundTrip) {
  for (const LensModel model : {LensModel::kRationalBrown, LensModel::kKannalaBrandt})
    EXPECT_EQ(lens_model_from_name(lens_model_name(model)), model);
  EXPECT_FALSE(lens_model_from_name("fisheye"));
  EXPECT_EQ(lens_coefficient_count(LensModel::kKannalaBrandt), 4);
  const Intrinsics in = fisheye_intrinsics();
  EXPECT_EQ(unpack(pack(in), in.width, in.height, in.lens_model).lens_model,
            LensModel::kKannalaBrandt);
}

TEST(CameraModel, IdealPixelIsDistortionFreeProjection) {
  Intrinsics in = typical_intrinsics();
  const CameraModel cam(in);
  in.dist = {};
  const CameraModel pinhole(in);
  const Vec2 xy(0.21, -0.13);
  EXPECT_LT((cam.ideal_pixel(xy) - *pinhole.project(Vec3(xy.x(), xy.y(), 1))).norm(), 1e-12);
}

}  // namespace
}  // namespace storetrack::camera
