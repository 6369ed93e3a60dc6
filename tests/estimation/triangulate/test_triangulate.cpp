// Triangulation against analytic truth: exactness without noise, honest centroid covariance
// (NEES), gains and calibration sensitivities against finite differences.
#include <cmath>
#include <cstdio>
#include <random>

#include <gtest/gtest.h>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "storetrack/uncertainty/calibration_factors.hpp"
#include "storetrack/uncertainty/statistics.hpp"
#include "synthetic_rig.hpp"

namespace storetrack::triangulate {
namespace {

using geometry::Vec2;
using geometry::Vec3;

std::vector<Observation> observe(const camera::RigCalibration& rig, const Vec3& p_w,
                                 double sigma_px, std::mt19937_64* rng) {
  std::vector<Observation> obs;
  std::normal_distribution<double> n(0, 1);
  for (const auto& cam : rig.cameras) {
    Observation o;
    o.model = &cam.model;
    o.T_c_w = cam.T_c_w;
    o.sigma_px = sigma_px;
    o.pixel_px = *cam.model.project_world(cam.T_c_w, p_w);
    if (rng) o.pixel_px += Vec2(n(*rng), n(*rng)) * sigma_px;
    obs.push_back(o);
  }
  return obs;
}

TEST(Triangulate, ExactWithoutNoiseFrom2To4Cameras) {
  const auto rig = test::synthetic_rig();
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(-0.4, 0.4);
  for (int trial = 0; trial < 50; ++trial) {
    const Vec3 p(u(rng), u(rng), 2.0 + u(rng));
    auto obs = observe(rig, p, 0.05, nullptr);
    for (size_t n = 2; n <= obs.size(); ++n) {
      Result r;
      ASSERT_TRUE(triangulate(std::span(obs.data(), n), Options{}, r));
      EXPECT_LT((r.p_w - p).norm(), 1e-9);
      for (const Vec2& res : r.residual_px)
        EXPECT_LT(res.norm(), 1e-6);
      const auto lin = triangulate_linear(std::span(obs.data(), n));
      ASSERT_TRUE(lin.has_value());
      EXPECT_LT((*lin - p).norm(), 1e-6);  // distortion removed exactly by unproject
    }
  }
}

// A mark at p moving at v seen without noise by the four cameras, each at its own time offset.
std::vector<Observation> observe_moving(const camera::RigCalibration& rig, const Vec3& p,
                                        const Vec3& v) {
  const double dt[4] = {0, 1e-4, -2e-4, 3e-4};
  std::vector<Observation> obs;
  for (size_t c = 0; c < 4; ++c) {
    Observation o;
    o.model = &rig.cameras[c].model;
    o.T_c_w = rig.cameras[c].T_c_w;
    o.displacement_w = v * dt[c];
    o.pixel_px = *o.model->project_world(o.T_c_w, p + o.displacement_w);
    obs.push_back(o);
  }
  return obs;
}

TEST(Triangulate, MotionDisplacementIsCompensated) {
  const auto rig = test::synthetic_rig();
  const Vec3 p(0.1, -0.2, 2.1), v(5.0, -3.0, 20.0);
  const std::vector<Observation> obs = observe_moving(rig, p, v);
  Result r;
  ASSERT_TRUE(triangulate(obs, Options{}, r));
  EXPECT_LT((r.p_w - p).norm(), 1e-9);
}

// A caller's projection of the start point replaces the first pass's projection; the later
// passes linearise exactly, so the solution is the truth whether the start projection is
// exact or off by pixels (a stale one), and the statistics match the projecting run.
TEST(Triangulate, StartProjectionOnlyShortensTheFirstPass) {
  const auto rig = test::synthetic_rig();
  const Vec3 p(0.1, -0.2, 2.1), v(5.0, -3.0, 20.0), start(0.103, -0.198, 2.095);
  std::vector<Observation> obs = observe_moving(rig, p, v);
  std::vector<StartProjection> exact(4), off(4);
  for (size_t c = 0; c < 4; ++c) {
    const Observation& o = obs[c];
    camera::ProjectionJacobians J;
    exact[c].pixel_px = *o.model->project_world(o.T_c_w, start, &J);
    exact[c].d_pixel_d_point_w = J.d_point_world;
    off[c] = exact[c];
    off[c].pixel_px += Vec2(3.0, -2.0);
  }
  Options options;
  options.initial_p_w = start;
  Result projecting;
  ASSERT_TRUE(triangulate(obs, options, projecting));
  EXPECT_LT((projecting.p_w - p).norm(), 1e-9);
  for (const auto* starts : {&exact, &off}) {
    for (size_t c = 0; c < 4; ++c)
      obs[c].start = &(*starts)[c];
    Result r;
    ASSERT_TRUE(triangulate(obs, options, r));
    EXPECT_LT((r.p_w - p).norm(), 1e-9);
    EXPECT_LT((r.cov_weighted - projecting.cov_weighted).norm(),
              1e-6 * projecting.cov_weighted.norm());
    EXPECT_NEAR(r.chi2, projecting.chi2, 1e-9);
    // The stale start was used (its first step lands further away: one more pass), the exact
    // one follows the projecting run's passes.
    if (starts == &off)
      EXPECT_GT(r.iterations, projecting.iterations);
    else
      EXPECT_EQ(r.iterations, projecting.iterations);
  }
}

TEST(Triangulate, CentroidCovarianceIsHonest) {
  const auto rig = test::synthetic_rig();
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<double> u(-0.4, 0.4);
  uncertainty::ConsistencyAccumulator<3> acc;
  for (int trial = 0; trial < 4000; ++trial) {
    const Vec3 p(u(rng), u(rng), 2.0 + u(rng));
    auto obs = observe(rig, p, 0.1, &rng);
    Result r;
    ASSERT_TRUE(triangulate(std::span(obs.data(), 2 + trial % 3), Options{}, r));
    acc.add(r.p_w - p, r.cov_centroid);
  }
  EXPECT_NEAR(acc.mean_nees(), 3.0, 0.15);
  for (int a = 0; a < 3; ++a)
    EXPECT_NEAR(acc.coverage(a), 0.9545, 0.012);
}

/// dp_w/d(pixel) of the solution against central differences of the whole triangulation.
void expect_gain_matches_finite_differences(const std::vector<Observation>& obs) {
  Result r;
  ASSERT_TRUE(triangulate(obs, Options{}, r));
  const double h = 1e-4;
  for (size_t i = 0; i < obs.size(); ++i) {
    for (int a = 0; a < 2; ++a) {
      auto plus = obs, minus = obs;
      plus[i].pixel_px(a) += h;
      minus[i].pixel_px(a) -= h;
      Result rp, rm;
      ASSERT_TRUE(triangulate(plus, Options{}, rp));
      ASSERT_TRUE(triangulate(minus, Options{}, rm));
      const Vec3 fd = (rp.p_w - rm.p_w) / (2 * h);
      // Gauss-Newton drops second derivatives of the projection: agreement to the residual
      // size, so with small residuals ~1e-3 relative.
      EXPECT_LT((fd - r.gain[i].col(a)).norm(), 2e-3 * fd.norm() + 1e-9) << i << " " << a;
    }
  }
}

TEST(Triangulate, GainMatchesFiniteDifferences) {
  const auto rig = test::synthetic_rig();
  std::mt19937_64 rng(3);
  const Vec3 p(0.2, 0.1, 2.2);
  expect_gain_matches_finite_differences(observe(rig, p, 0.1, &rng));
}

/// Correlated, per camera different pixel covariances (as the matcher's centroid plus
/// calibration part): the weight is the full 2x2 information matrix.
std::vector<geometry::Mat2> pixel_covariances(size_t n) {
  std::vector<geometry::Mat2> C(n);
  for (size_t i = 0; i < n; ++i) {
    const double a = 0.05 + 0.04 * static_cast<double>(i), b = 0.2 - 0.03 * static_cast<double>(i);
    const double rho = i % 2 ? 0.7 : -0.5;
    C[i] << a * a, rho * a * b, rho * a * b, b * b;
  }
  return C;
}

TEST(Triangulate, FullInformationMatrixCovarianceIsHonest) {
  // Noise drawn with covariance C_k, weight C_k^-1: the estimate's scatter must match
  // cov_centroid (NEES 3) and chi2 must follow chi-square with 2n - 3 dof (mean 2n - 3).
  const auto rig = test::synthetic_rig();
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-0.4, 0.4);
  std::normal_distribution<double> n01(0, 1);
  const auto C = pixel_covariances(rig.cameras.size());
  uncertainty::ConsistencyAccumulator<3> acc;
  double chi2_sum = 0, dof_sum = 0;
  for (int trial = 0; trial < 4000; ++trial) {
    const Vec3 p(u(rng), u(rng), 2.0 + u(rng));
    auto obs = observe(rig, p, 0.1, nullptr);
    const size_t n = 2 + static_cast<size_t>(trial % 3);
    for (size_t i = 0; i < obs.size(); ++i) {
      const geometry::Mat2 L = C[i].llt().matrixL();
      obs[i].pixel_px += L * Vec2(n01(rng), n01(rng));
      obs[i].information_px = C[i].inverse();
      obs[i].sigma_px = 1e3;  // cov_weighted and chi2 ignore it when the information is set
    }
    Result r;
    ASSERT_TRUE(triangulate(std::span(obs.data(), n), Options{}, r));
    acc.add(r.p_w - p, r.cov_weighted);
    chi2_sum += r.chi2;
    dof_sum += 2.0 * static_cast<double>(n) - 3;
  }
  EXPECT_NEAR(acc.mean_nees(), 3.0, 0.15);
  for (int a = 0; a < 3; ++a)
    EXPECT_NEAR(acc.coverage(a), 0.9545, 0.012);
  // chi2 sum over trials: mean dof_sum, variance 2 dof_sum; 5 sigma.
  EXPECT_NEAR(chi2_sum, dof_sum, 5 * std::sqrt(2 * dof_sum));
}

TEST(Triangulate, FullInformationGainMatchesFiniteDifferences) {
  const auto rig = test::synthetic_rig();
  std::mt19937_64 rng(6);
  const Vec3 p(-0.1, 0.2, 2.3);
  auto obs = observe(rig, p, 0.1, &rng);
  const auto C = pixel_covariances(obs.size());
  for (size_t i = 0; i < obs.size(); ++i)
    obs[i].information_px = C[i].inverse();
  expect_gain_matches_finite_differences(obs);
}

TEST(Triangulate, CalibrationSensitivityMatchesFiniteDifferences) {
  // dp/dtheta = -K dproj/dtheta, the chain the pipeline uses for the calibration budget.
  const auto rig = test::synthetic_rig();
  const Vec3 p(-0.2, 0.25, 1.8);
  auto obs = observe(rig, p, 0.1, nullptr);
  Result r;
  ASSERT_TRUE(triangulate(obs, Options{}, r));
  const size_t cam = 1;
  // Intrinsics.
  const camera::IntrinsicVector v0 = camera::pack(rig.cameras[cam].model.intrinsics());
  for (int k = 0; k < 10; ++k) {
    const double h = k < 5 ? 1e-3 : 1e-6;
    camera::CameraModel mp(camera::unpack(v0 + h * camera::IntrinsicVector::Unit(k), 1920, 1024,
                                          camera::LensModel::kRationalBrown));
    camera::CameraModel mm(camera::unpack(v0 - h * camera::IntrinsicVector::Unit(k), 1920, 1024,
                                          camera::LensModel::kRationalBrown));
    auto op = obs, om = obs;
    op[cam].model = &mp;
    om[cam].model = &mm;
    Result rp, rm;
    ASSERT_TRUE(triangulate(op, Options{}, rp));
    ASSERT_TRUE(triangulate(om, Options{}, rm));
    const Vec3 fd = (rp.p_w - rm.p_w) / (2 * h);
    const Vec3 an = -r.gain[cam] * r.jacobians[cam].d_intrinsics.col(k);
    EXPECT_LT((fd - an).norm(), 1e-4 * fd.norm() + 1e-9) << "intrinsic " << k;
  }
  // Extrinsics (left perturbation of T_c_w).
  for (int k = 0; k < 6; ++k) {
    const double h = 1e-6;
    auto op = obs, om = obs;
    op[cam].T_c_w = geometry::perturb_left(obs[cam].T_c_w, h * geometry::Vec6::Unit(k));
    om[cam].T_c_w = geometry::perturb_left(obs[cam].T_c_w, -h * geometry::Vec6::Unit(k));
    Result rp, rm;
    ASSERT_TRUE(triangulate(op, Options{}, rp));
    ASSERT_TRUE(triangulate(om, Options{}, rm));
    const Vec3 fd = (rp.p_w - rm.p_w) / (2 * h);
    const Vec3 an = -r.gain[cam] * r.jacobians[cam].d_pose.col(k);
    EXPECT_LT((fd - an).norm(), 1e-4 * fd.norm() + 1e-9) << "extrinsic " << k;
  }
}

TEST(Triangulate, RayMidpointAgainstIntersectionAndPerpendicularity) {
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int trial = 0; trial < 500; ++trial) {
    const Vec3 c1(u(rng), u(rng), u(rng)), c2(u(rng) + 2, u(rng), u(rng));
    const Vec3 X(u(rng), u(rng), 5 + 3 * u(rng));
    // Intersecting rays (directions of any length): the point itself.
    const Vec3 d1 = (X - c1) * (0.5 + std::abs(u(rng))), d2 = (X - c2) * 3.0;
    const auto mid = ray_midpoint(c1, d1, c2, d2);
    ASSERT_TRUE(mid);
    EXPECT_LT((*mid - X).norm(), 1e-9);
    // Skew rays: the segment between the closest points is perpendicular to both lines (their
    // definition), and the midpoint is its centre.
    const Vec3 d2s = d2 + Vec3(u(rng), u(rng), u(rng)) * 0.2;
    const auto m = ray_midpoint(c1, d1, c2, d2s);
    ASSERT_TRUE(m);
    const Vec3 n = d1.cross(d2s).normalized();
    const double half_gap = 0.5 * n.dot(c2 - c1);  // signed half distance between the lines
    const Vec3 p1 = *m - half_gap * n, p2 = *m + half_gap * n;  // on line 1 and line 2
    EXPECT_LT((p1 - c1).cross(d1).norm(), 1e-9 * d1.norm() * (1 + (p1 - c1).norm()));
    EXPECT_LT((p2 - c2).cross(d2s).norm(), 1e-9 * d2s.norm() * (1 + (p2 - c2).norm()));
  }
  // Parallel rays and a point behind a centre: none.
  EXPECT_FALSE(ray_midpoint(Vec3(0, 0, 0), Vec3(0, 0, 1), Vec3(1, 0, 0), Vec3(0, 0, 2)));
  EXPECT_FALSE(ray_midpoint(Vec3(0, 0, 0), Vec3(0, 0, -1), Vec3(1, 0, 0), Vec3(-1, 0, 1)));
}

TEST(Triangulate, RejectsDegenerateInput) {
  const auto rig = test::synthetic_rig();
  auto obs = observe(rig, Vec3(0, 0, 2), 0.1, nullptr);
  Result r;
  EXPECT_FALSE(triangulate(std::span(obs.data(), 1), Options{}, r));
  obs[1] = obs[0];  // same camera twice: parallel rays
  EXPECT_FALSE(triangulate_linear(std::span(obs.data(), 2)).has_value());
}

TEST(Triangulate, CentroidPartThroughGainsIsHonestUnderCalibrationWeights) {
  // The host weighs each view by (sigma^2 I + S_cal)^-1 but states the centroid part alone:
  // with pixel noise of sigma only (no calibration error drawn), cov_centroid = sum K sigma^2
  // K^T must match the scatter (NEES 3, 4000 trials: mean within +-0.15 is > 5 sigma of its
  // spread sqrt(6 / 4000) = 0.039), while cov_weighted, which adds the calibration part, must
  // overstate it.
  const auto rig = test::synthetic_rig();
  std::mt19937_64 rng(6);
  std::uniform_real_distribution<double> u(-0.4, 0.4);
  const auto S = pixel_covariances(rig.cameras.size());
  const double sigma = 0.1;
  uncertainty::ConsistencyAccumulator<3> centroid, weighted;
  for (int trial = 0; trial < 4000; ++trial) {
    const Vec3 p(u(rng), u(rng), 2.0 + u(rng));
    auto obs = observe(rig, p, sigma, &rng);
    const size_t n = 2 + static_cast<size_t>(trial % 3);
    for (size_t i = 0; i < obs.size(); ++i)
      obs[i].information_px = (sigma * sigma * geometry::Mat2::Identity() + S[i]).inverse();
    Result r;
    ASSERT_TRUE(triangulate(std::span(obs.data(), n), Options{}, r));
    centroid.add(r.p_w - p, r.cov_centroid);
    weighted.add(r.p_w - p, r.cov_weighted);
  }
  EXPECT_NEAR(centroid.mean_nees(), 3.0, 0.15);
  for (int a = 0; a < 3; ++a)
    EXPECT_NEAR(centroid.coverage(a), 0.9545, 0.012);
  EXPECT_LT(weighted.mean_nees(), 2.0);
}

/// synthetic_rig() with Kannala-Brandt fisheyes (f = 420 px on 1920 x 1024: a ~180-degree
/// field) and their stated uncertainty, read back through the calibration file.
camera::RigCalibration fisheye_rig() {
  camera::RigCalibration rig = test::synthetic_rig();
  for (camera::CalibratedCamera& cam : rig.cameras) {
    camera::Intrinsics in = cam.model.intrinsics();
    in.lens_model = camera::LensModel::kKannalaBrandt;
    in.fx = 421.7;
    in.fy = 420.9;
    in.dist = {-0.013, -0.0067, 0.0037, -0.0012, 0, 0, 0, 0};
    cam.model = camera::CameraModel(in);
    camera::IntrinsicVector sd = camera::IntrinsicVector::Zero();
    sd << 0.2, 0.2, 0.15, 0.15, 0, 2e-4, 3e-4, 2e-4, 5e-5, 0, 0, 0, 0;
    cam.intrinsic_covariance = sd.cwiseAbs2().asDiagonal();
  }
  return camera::parse_rig_calibration(camera::format_rig_calibration(rig), "fisheye rig");
}

TEST(Triangulate, FisheyeRigIsHonestWithCalibrationUncertainty) {
  // Marks out to 85 degrees off the cameras' axes, pixels from the true fisheye rig with 0.1 px
  // noise, triangulated with a calibration drawn from its stated (diagonal) covariance (JCGM
  // 101), covariance = centroid part + the calibration's through the gains
  // (uncertainty::point_sensitivity). Sum of N = 2000 NEES ~ chi-square(3 N): inside its
  // two-sided 99.9 % interval.
  const camera::RigCalibration truth = fisheye_rig();
  ASSERT_EQ(truth.cameras[0].model.intrinsics().lens_model, camera::LensModel::kKannalaBrandt);
  std::mt19937_64 rng(28);
  std::uniform_real_distribution<double> u(-1, 1);
  std::normal_distribution<double> n(0, 1);
  const double sigma = 0.1;
  constexpr int kTrials = 2000;
  double nees_sum = 0, widest_deg = 0;
  for (int trial = 0; trial < kTrials; ++trial) {
    const Vec3 p(3 * u(rng), 3 * u(rng), 1.5 + 1.0 * u(rng));
    camera::RigCalibration stated = truth;
    for (camera::CalibratedCamera& cam : stated.cameras) {
      camera::IntrinsicVector v = camera::pack(cam.model.intrinsics());
      for (int k = 0; k < camera::kNumIntrinsics; ++k)
        v[k] += std::sqrt(cam.intrinsic_covariance(k, k)) * n(rng);
      const camera::Intrinsics& in = cam.model.intrinsics();
      cam.model = camera::CameraModel(camera::unpack(v, in.width, in.height, in.lens_model));
      geometry::Vec6 d;
      for (int k = 0; k < 6; ++k)
        d[k] = std::sqrt(cam.extrinsic_covariance(k, k)) * n(rng);
      cam.T_c_w = geometry::perturb_left(cam.T_c_w, d);
    }
    std::vector<Observation> obs;
    std::vector<int> slots;
    for (size_t c = 0; c < truth.cameras.size(); ++c) {
      const Vec3 p_cam = truth.cameras[c].T_c_w * p;
      const double off_axis = std::atan2(p_cam.head<2>().norm(), p_cam.z());
      if (off_axis > 85 * M_PI / 180) continue;
      widest_deg = std::max(widest_deg, off_axis * 180 / M_PI);
      Observation o;
      o.model = &stated.cameras[c].model;
      o.T_c_w = stated.cameras[c].T_c_w;
      o.sigma_px = sigma;
      o.pixel_px = *truth.cameras[c].model.project_world(truth.cameras[c].T_c_w, p) +
                   Vec2(n(rng), n(rng)) * sigma;
      obs.push_back(o);
      slots.push_back(static_cast<int>(c));
    }
    if (obs.size() < 2) {
      --trial;
      continue;
    }
    Result r;
    ASSERT_TRUE(triangulate(obs, Options{}, r)) << "trial " << trial;
    geometry::Mat3 cov = r.cov_centroid;
    for (size_t i = 0; i < obs.size(); ++i) {
      const camera::CalibratedCamera& cam = stated.cameras[static_cast<size_t>(slots[i])];
      uncertainty::CameraCovariance C = uncertainty::CameraCovariance::Zero();
      C.topLeftCorner<camera::kNumIntrinsics, camera::kNumIntrinsics>() = cam.intrinsic_covariance;
      C.bottomRightCorner<6, 6>() = cam.extrinsic_covariance;
      const uncertainty::CameraSensitivity G =
          uncertainty::point_sensitivity(r.gain[i], r.jacobians[i]);
      cov += G * C * G.transpose();
    }
    const Vec3 e = r.p_w - p;
    nees_sum += e.dot(cov.ldlt().solve(e));
  }
  const uncertainty::DegreesOfFreedom dof(3 * kTrials);
  std::printf("fisheye rig: mean NEES %.3f (dimension 3) over %d marks, widest view %.1f deg\n",
              nees_sum / kTrials, kTrials, widest_deg);
  EXPECT_GT(widest_deg, 80);
  EXPECT_GT(nees_sum, uncertainty::chi_square_quantile(uncertainty::Probability(0.0005), dof));
  EXPECT_LT(nees_sum, uncertainty::chi_square_quantile(uncertainty::Probability(0.9995), dof));
}

}  // namespace
}  // namespace storetrack::triangulate
