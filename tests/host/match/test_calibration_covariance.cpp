// One calibration covariance for the gates and the stated uncertainty (issue 29): the matcher's
// gate covariance of a mark's pixel and the processor's stated covariance of the mark come from
// the same calibration errors, cross terms included. Truth is the calibration file's joint
// covariance itself, propagated here by plain matrix products over the raw parameters (not the
// whitened factors the host uses).
#include <set>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "storetrack/match/mark_matcher.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "storetrack/uncertainty/calibration_factors.hpp"
#include "synthetic_rig.hpp"

namespace storetrack {
namespace {

constexpr int kBlock = camera::kJointBlockSize;

/// The synthetic rig with a version-2 joint covariance: the cameras' own blocks plus a shared
/// low-rank part (board poses and world registration seen by all cameras) that correlates
/// intrinsics with extrinsics and cameras with each other. Its scale is each parameter's own
/// standard deviation, so the cross terms are of the same order as the blocks.
camera::RigCalibration rig_with_cross_terms() {
  camera::RigCalibration rig = test::synthetic_rig();
  const Eigen::MatrixXd blocks = rig.full_joint_covariance();
  const Eigen::Index n = blocks.rows();
  std::mt19937 rng(29);
  std::normal_distribution<double> normal;
  Eigen::MatrixXd D(n, 8);
  for (Eigen::Index r = 0; r < n; ++r)
    for (Eigen::Index c = 0; c < D.cols(); ++c)
      D(r, c) = 0.4 * std::sqrt(blocks(r, r)) * normal(rng);
  camera::set_joint_covariance(rig, blocks + D * D.transpose());
  return rig;
}

/// J Sigma_c J^T from the file's raw 19 x 19 block of camera `slot`.
geometry::Mat2 file_pixel_covariance(const camera::RigCalibration& rig, int slot,
                                     const camera::ProjectionJacobians& J) {
  Eigen::Matrix<double, 2, kBlock> Jc;
  Jc << J.d_intrinsics, J.d_pose;
  return Jc * rig.joint_covariance.block<kBlock, kBlock>(kBlock * slot, kBlock * slot) *
         Jc.transpose();
}

double relative_difference(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return (a - b).norm() / b.norm();
}

const std::vector<geometry::Vec3> kPoints = {
    {0, 0, 2.0}, {0.3, -0.2, 1.8}, {-0.25, 0.3, 2.3}, {0.1, 0.35, 2.1}};

TEST(CalibrationCovariance, GateCovarianceIsTheFilesJointBlockWithCrossTerm) {
  const camera::RigCalibration rig = rig_with_cross_terms();
  ASSERT_TRUE(rig.has_cross_covariance());
  const match::MarkMatcher matcher(rig, {});
  const uncertainty::CalibrationFactors processor_factors(rig);  // as ExposureProcessor builds it
  double largest_dropped = 0;
  for (const geometry::Vec3& p_w : kPoints)
    for (int slot = 0; slot < static_cast<int>(rig.cameras.size()); ++slot) {
      const camera::CalibratedCamera& cam = rig.cameras[static_cast<size_t>(slot)];
      camera::ProjectionJacobians J;
      ASSERT_TRUE(cam.model.project_world(cam.T_c_w, p_w, &J));
      const geometry::Mat2 truth = file_pixel_covariance(rig, slot, J);
      const geometry::Mat2 gate = matcher.calibration_pixel_covariance(slot, p_w);
      // The factors drop eigenvalues below 1e-12 of the largest (correlation scale).
      EXPECT_LT(relative_difference(gate, truth), 1e-8) << "slot " << slot;
      EXPECT_LT(
          relative_difference(uncertainty::pixel_covariance(processor_factors, slot, J), gate),
          1e-12);
      // Without the intrinsic-extrinsic cross term (the old gate): the test can tell them apart.
      const geometry::Mat2 blocks_only =
          J.d_intrinsics * cam.intrinsic_covariance * J.d_intrinsics.transpose() +
          J.d_pose * cam.extrinsic_covariance * J.d_pose.transpose();
      largest_dropped = std::max(largest_dropped, relative_difference(blocks_only, truth));
    }
  std::printf("largest relative difference of the blocks-only pixel covariance: %.3f\n",
              largest_dropped);
  EXPECT_GT(largest_dropped, 1e-3);
}

TEST(CalibrationCovariance, StatedMarkCovarianceIsTheFilesJointPropagation) {
  const camera::RigCalibration rig = rig_with_cross_terms();
  const uncertainty::CalibrationFactors factors(rig);
  ASSERT_TRUE(factors.coupled());
  const auto [sync_begin, sync_count] = factors.range(uncertainty::Source::kSync);
  for (const geometry::Vec3& p_w : kPoints) {
    std::vector<triangulate::Observation> obs;
    for (const camera::CalibratedCamera& cam : rig.cameras) {
      const auto pixel = cam.model.project_world(cam.T_c_w, p_w);
      ASSERT_TRUE(pixel);
      triangulate::Observation o;
      o.model = &cam.model;
      o.T_c_w = cam.T_c_w;
      o.pixel_px = *pixel;
      obs.push_back(o);
    }
    triangulate::Result tri;
    ASSERT_TRUE(triangulate::triangulate(obs, triangulate::Options{}, tri));
    // The processor's stated calibration covariance: loadings on the factors, L L^T.
    uncertainty::Loadings3 loadings = uncertainty::Loadings3::Zero(3, factors.num_factors());
    Eigen::Matrix3d unused_intrinsic = Eigen::Matrix3d::Zero(), unused_extrinsic = unused_intrinsic;
    // Truth: G Sigma G^T over the raw parameters, G_i = -K_i [J_I J_E] written out here.
    Eigen::MatrixXd G = Eigen::MatrixXd::Zero(3, rig.joint_covariance.cols());
    for (int i = 0; i < static_cast<int>(obs.size()); ++i) {
      uncertainty::add_observation_loadings(factors, i, tri.gain[static_cast<size_t>(i)],
                                            tri.jacobians[static_cast<size_t>(i)], loadings,
                                            unused_intrinsic, unused_extrinsic);
      G.block<3, camera::kNumIntrinsics>(0, kBlock * i) =
          -tri.gain[static_cast<size_t>(i)] * tri.jacobians[static_cast<size_t>(i)].d_intrinsics;
      G.block<3, 6>(0, kBlock * i + camera::kNumIntrinsics) =
          -tri.gain[static_cast<size_t>(i)] * tri.jacobians[static_cast<size_t>(i)].d_pose;
    }
    const Eigen::MatrixXd calibration = loadings.leftCols(sync_begin);
    const Eigen::Matrix3d stated = calibration * calibration.transpose();
    const Eigen::Matrix3d truth = G * rig.joint_covariance * G.transpose();
    EXPECT_LT(relative_difference(stated, truth), 1e-8);
    // The sync factors are the columns after the calibration's: one per camera (its calibrated
    // offset) and one per unit (its clock, shared by the unit's cameras).
    std::set<int> units;
    for (const camera::CalibratedCamera& cam : rig.cameras)
      units.insert(cam.unit_id);
    EXPECT_EQ(sync_count, static_cast<int>(rig.cameras.size() + units.size()));
  }
}

}  // namespace
}  // namespace storetrack
