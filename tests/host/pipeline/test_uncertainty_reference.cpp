// Regression test of the per-exposure fast path (whitened factor loadings, fixed-size products,
// structured normal matrices; docs/performance.md "Host processing") against the
// straightforward reference computation of the same first-order propagation (GUM JCGM
// 100:2008, 5.2): dense sensitivities to every camera's 13 intrinsics, 6 extrinsics and time
// offset, contracted with the calibration file's covariance matrices directly (no factor form),
// for every mark, the pylon and store poses and T_p_s with its (x, y, z, yaw, pitch, roll).
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "sim_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/pose/body_pose.hpp"
#include "storetrack/triangulate/triangulate.hpp"

namespace storetrack::pipeline {
namespace {

using geometry::Mat3;
using geometry::Mat6;
using geometry::Vec3;
using uncertainty::Source;
constexpr int kPerCamera = camera::kNumIntrinsics + 6 + 1;  // intrinsics, pose, time offset
using DenseSens3 = Eigen::Matrix<double, 3, Eigen::Dynamic>;
using DenseSens6 = Eigen::Matrix<double, 6, Eigen::Dynamic>;

size_t idx(Source s) {
  return static_cast<size_t>(uncertainty::index(s));
}

// Covariance of the parameters of one source, all cameras, dense. Block diagonal but for the
// time offsets: each camera's is its calibrated offset's error plus its unit's clock error
// (`clock_sigma_s`, the exposure's stated figure), one clock shared by the unit's cameras.
Eigen::MatrixXd source_covariance(const camera::RigCalibration& rig, Source s,
                                  double clock_sigma_s) {
  const int n = static_cast<int>(rig.cameras.size());
  Eigen::MatrixXd C = Eigen::MatrixXd::Zero(n * kPerCamera, n * kPerCamera);
  for (int c = 0; c < n; ++c) {
    const auto& cam = rig.cameras[static_cast<size_t>(c)];
    const int b = c * kPerCamera;
    if (s == Source::kIntrinsic)
      C.block<camera::kNumIntrinsics, camera::kNumIntrinsics>(b, b) = cam.intrinsic_covariance;
    if (s == Source::kExtrinsic)
      C.block<6, 6>(b + camera::kNumIntrinsics, b + camera::kNumIntrinsics) =
          cam.extrinsic_covariance;
    if (s != Source::kSync) continue;
    C(b + kPerCamera - 1, b + kPerCamera - 1) = std::pow(cam.exposure_offset_sigma_ns * 1e-9, 2);
    for (int d = 0; d < n; ++d)
      if (rig.cameras[static_cast<size_t>(d)].unit_id == cam.unit_id)
        C(b + kPerCamera - 1, d * kPerCamera + kPerCamera - 1) += clock_sigma_s * clock_sigma_s;
  }
  return C;
}

double relative_difference(const Eigen::MatrixXd& a, const Eigen::MatrixXd& ref) {
  return (a - ref).norm() / std::max(ref.norm(), 1e-300);
}

struct MarkReference {
  Vec3 p_w;
  Mat3 cov_centroid;
  DenseSens3 d_theta;  // dp_w / d(all cameras' parameters)
};

TEST(UncertaintyReference, FastPathMatchesDenseReference) {
  const sim::Simulator sim(sim::load_scenario(test::scenario_path("store_separation")), 23);
  const camera::RigCalibration rig = sim.calibrated_rig();
  ExposureProcessor proc(rig, sim.pylon_survey(), sim.store_survey(), ProcessorConfig{});
  const int n_cam = static_cast<int>(rig.cameras.size());
  // The simulator's units state their clock's sigma, the spread of its stamp errors.
  const double clock_sigma_s = sim.scenario().ptp_offset_sigma_ns * 1e-9;
  ASSERT_GT(clock_sigma_s, 0);
  std::array<Eigen::MatrixXd, uncertainty::kNumSources> Sigma;
  for (Source s : {Source::kIntrinsic, Source::kExtrinsic, Source::kSync})
    Sigma[idx(s)] = source_covariance(rig, s, clock_sigma_s);

  int exposures_checked = 0, marks_checked = 0;
  for (int k : {40, 41, 42, 120, 121, 200}) {
    const test::SimExposure in = test::make_exposure(sim, k);
    for (const msg::MarkObservations& o : in.exposure.cameras)
      ASSERT_EQ(o.exposure_time_sigma_ns, std::llround(clock_sigma_s * 1e9));
    const ExposureResult r = proc.process(in.exposure, in.ids);
    if (k == 40 || k == 120) continue;  // first of a track: velocities not yet known
    ASSERT_TRUE(r.T_p_s.valid);
    std::vector<MarkReference> refs;
    for (const MarkResult& m : r.marks) {
      // Re-triangulate from the same observations (same weights; motion-compensated with the
      // same velocity where the host was).
      std::vector<triangulate::Observation> obs;
      std::vector<int> slot;
      for (const auto& o : m.observations) {
        size_t e = 0;
        while (in.exposure.cameras[e].camera_id != o.camera_id)
          ++e;
        int c = 0;
        while (rig.cameras[static_cast<size_t>(c)].camera_id != o.camera_id)
          ++c;
        const auto& cam = rig.cameras[static_cast<size_t>(c)];
        const auto& mo = in.exposure.cameras[e].marks[static_cast<size_t>(o.mark_index)];
        const time::TaiNs t_cam = exposure_mid_tai_ns(in.exposure.cameras[e]) +
                                  static_cast<time::TaiNs>(std::llround(cam.exposure_offset_ns));
        triangulate::Observation t;
        t.model = &cam.model;
        t.T_c_w = cam.T_c_w;
        t.pixel_px = geometry::Vec2(mo.x_px, mo.y_px);
        t.sigma_px = o.sigma_px;
        t.information_px = o.information_px;  // the matcher's weight
        if (m.motion_corrected)
          t.displacement_w =
              m.velocity_w * (static_cast<double>(t_cam - r.reference_mid_tai_ns) * 1e-9);
        obs.push_back(t);
        slot.push_back(c);
      }
      triangulate::Result tri;
      ASSERT_TRUE(triangulate::triangulate(obs, triangulate::Options{}, tri));
      MarkReference ref;
      ref.p_w = tri.p_w;
      ref.cov_centroid = tri.cov_centroid;
      ref.d_theta = DenseSens3::Zero(3, n_cam * kPerCamera);
      for (size_t i = 0; i < obs.size(); ++i) {
        const int b = slot[i] * kPerCamera;
        const auto& J = tri.jacobians[i];
        ref.d_theta.middleCols<camera::kNumIntrinsics>(b) = -tri.gain[i] * J.d_intrinsics;
        ref.d_theta.middleCols<6>(b + camera::kNumIntrinsics) = -tri.gain[i] * J.d_pose;
        if (m.velocity_valid)
          ref.d_theta.col(b + kPerCamera - 1) = -tri.gain[i] * (J.d_point_world * m.velocity_w);
      }
      EXPECT_LT((ref.p_w - m.p_w).norm(), 1e-9) << "mark " << m.id;
      // The host's Gauss-Newton keeps the Jacobians of its last pass, one step shorter than its
      // tolerance (match::estimator_options: 10 um) before the solution: a relative change of
      // that step over the depth, < 1e-7 here (quadratic convergence leaves the last step far
      // below the tolerance); the reference is triangulated again from the linear start.
      EXPECT_LT(relative_difference(m.cov_by_source[idx(Source::kCentroid)], ref.cov_centroid),
                1e-6);
      Mat3 total = ref.cov_centroid;
      for (Source s : {Source::kIntrinsic, Source::kExtrinsic, Source::kSync}) {
        const Mat3 c = ref.d_theta * Sigma[idx(s)] * ref.d_theta.transpose();
        total += c;
        if (c.norm() > 0) {
          EXPECT_LT(relative_difference(m.cov_by_source[idx(s)], c), 1e-6)
              << "mark " << m.id << " source " << uncertainty::kSourceNames[idx(s)];
        }
      }
      EXPECT_LT(relative_difference(m.cov_w, total), 1e-6) << "mark " << m.id;
      refs.push_back(ref);
      ++marks_checked;
    }

    // Body poses with the processor's exclusions and weights (the marks' total covariances).
    struct BodyReference {
      geometry::Transform T;
      DenseSens6 d_theta;
      Mat6 cov_centroid = Mat6::Zero(), cov_survey = Mat6::Zero();
    };
    auto body = [&](char which, const survey::RigidBodySurvey& survey) {
      std::vector<Vec3> q, p;
      std::vector<Mat3> cov;
      std::vector<double> sigma;
      std::vector<size_t> used;
      for (size_t i = 0; i < r.marks.size(); ++i) {
        const MarkResult& m = r.marks[i];
        if (m.body != which || m.excluded) continue;
        q.push_back(survey.find(m.id)->p_body);
        sigma.push_back(survey.find(m.id)->sigma_m);
        p.push_back(m.p_w);
        cov.push_back(m.cov_w);
        used.push_back(i);
      }
      pose::BodyFit fit;
      EXPECT_TRUE(pose::fit_body(pose::PointsInBody{q}, pose::PointsInWorld{p}, cov, sigma, fit));
      BodyReference b;
      b.T = fit.T_w_b;
      b.d_theta = DenseSens6::Zero(6, n_cam * kPerCamera);
      for (size_t j = 0; j < used.size(); ++j) {
        const auto& D = fit.d_pose_d_point[j];
        b.d_theta += D * refs[used[j]].d_theta;
        b.cov_centroid += D * refs[used[j]].cov_centroid * D.transpose();
        b.cov_survey +=
            sigma[j] * sigma[j] * fit.d_pose_d_survey[j] * fit.d_pose_d_survey[j].transpose();
      }
      return b;
    };
    const BodyReference pylon = body('p', sim.pylon_survey());
    const BodyReference store = body('s', sim.store_survey());
    Mat6 A_p, A_s;
    pose::relative_pose_jacobians(pylon.T, store.T, A_p, A_s);
    const DenseSens6 d_ps = A_p * pylon.d_theta + A_s * store.d_theta;
    // Zeros for the sources a solved pose has none of (kProcess: extrapolation only).
    std::array<Mat6, uncertainty::kNumSources> ref_ps = zero_by_source<Mat6>();
    ref_ps[idx(Source::kCentroid)] =
        A_p * pylon.cov_centroid * A_p.transpose() + A_s * store.cov_centroid * A_s.transpose();
    ref_ps[idx(Source::kSurvey)] =
        A_p * pylon.cov_survey * A_p.transpose() + A_s * store.cov_survey * A_s.transpose();
    for (Source s : {Source::kIntrinsic, Source::kExtrinsic, Source::kSync})
      ref_ps[idx(s)] = d_ps * Sigma[idx(s)] * d_ps.transpose();
    Mat6 total = Mat6::Zero();
    for (size_t s = 0; s < ref_ps.size(); ++s) {
      total += ref_ps[s];
      EXPECT_LT(relative_difference(r.T_p_s.cov_by_source[s], ref_ps[s]), 1e-6)
          << "k " << k << " source " << uncertainty::kSourceNames[s];
    }
    EXPECT_LT(relative_difference(r.T_p_s.cov, total), 1e-6) << "k " << k;
    // Pose itself and the reported (x, y, z, yaw, pitch, roll) covariance.
    const geometry::Transform T_ps = pylon.T.inverse() * store.T;
    EXPECT_LT((T_ps.translation() - r.T_p_s.T.translation()).norm(), 1e-9);
    EXPECT_LT((T_ps.linear() - r.T_p_s.T.linear()).norm(), 1e-9);
    Mat6 J = Mat6::Zero();
    J.topRightCorner<3, 3>() = Mat3::Identity();
    J.bottomLeftCorner<3, 3>() = pose::ypr_jacobian(T_ps.linear());
    EXPECT_LT(relative_difference(r.cov_xyz_ypr, J * total * J.transpose()), 1e-6) << "k " << k;
    ++exposures_checked;
  }
  EXPECT_EQ(exposures_checked, 4);
  EXPECT_GT(marks_checked, 40);
}

}  // namespace
}  // namespace storetrack::pipeline
