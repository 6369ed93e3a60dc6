// BodyMotion, the one motion state of a body (issue 29): the pose filter's prediction and
// start against closed forms (the full 12 x 12 transition F P F^T + Q written out, not the
// 6 x 6 blocks the filter uses), and the solved-pose history's order and reset.
#include <gtest/gtest.h>

#include <cstdlib>
#include <limits>

#include "storetrack/match/body_motion.hpp"

namespace storetrack::match {
namespace {

using geometry::Mat3;
using geometry::Mat6;
using geometry::Transform;
using geometry::Vec3;
using Mat12 = PoseFilter::Mat12;

Mat12 random_spd(unsigned seed) {
  std::srand(seed);
  const Mat12 A = Mat12::Random();
  return A * A.transpose() + 1e-3 * Mat12::Identity();
}

TEST(PointCovariance, IsTheDenseJacobianProduct) {
  for (unsigned seed = 1; seed <= 20; ++seed) {
    const Mat12 A = random_spd(seed);
    const Mat6 P = A.topLeftCorner<6, 6>();
    const Transform T = geometry::make_transform(Vec3::Random(), Vec3::Random());
    const Vec3 p_b = Vec3::Random();
    // d(T p_b) / d(phi, rho) for R <- Exp(phi) R, t <- t + rho, written out.
    Eigen::Matrix<double, 3, 6> G;
    G << -geometry::skew(T.linear() * p_b), Mat3::Identity();
    const Mat3 dense = G * P * G.transpose();
    EXPECT_LT((point_covariance(T, p_b, P) - dense).norm(), 1e-12 * dense.norm()) << seed;
  }
}

TEST(PoseFilter, PredictionIsTheConstantVelocityModelWithWhiteNoiseAcceleration) {
  PoseFilter f;
  f.valid = true;
  f.t_s = 0.75;
  f.T_w_b.linear() = geometry::rotation_from_rotvec(Vec3(0.1, -0.2, 0.3));
  f.T_w_b.translation() = Vec3(1.0, 2.0, -0.5);
  f.omega_w = Vec3(0.4, -0.3, 1.2);
  f.v_w = Vec3(-2.0, 0.5, 9.0);
  f.P = random_spd(7);
  const double dt = 0.0025, qa = 30.0, ql = 80.0;
  const PoseFilter p = f.predicted(f.t_s + dt, qa, ql);

  EXPECT_TRUE(p.valid);
  EXPECT_DOUBLE_EQ(p.t_s, f.t_s + dt);
  const Mat3 R_expected = geometry::rotation_from_rotvec(f.omega_w * dt) * f.T_w_b.linear();
  EXPECT_LT((p.T_w_b.linear() - R_expected).norm(), 1e-15);
  EXPECT_LT((p.T_w_b.translation() - (f.T_w_b.translation() + f.v_w * dt)).norm(), 1e-15);
  EXPECT_EQ(p.omega_w, f.omega_w);
  EXPECT_EQ(p.v_w, f.v_w);

  // F = [I dt I; 0 I] over (pose, rates); Q = G G^T sigma^2 per axis with G = (dt^2 / 2, dt).
  Mat12 F = Mat12::Identity();
  F.topRightCorner<6, 6>() = dt * Mat6::Identity();
  Mat12 Q = Mat12::Zero();
  for (int i = 0; i < 6; ++i) {
    const double s2 = i < 3 ? qa * qa : ql * ql;
    Eigen::Vector2d g(dt * dt / 2, dt);
    const Eigen::Matrix2d block = s2 * g * g.transpose();
    Q(i, i) = block(0, 0);
    Q(i, 6 + i) = Q(6 + i, i) = block(0, 1);
    Q(6 + i, 6 + i) = block(1, 1);
  }
  const Mat12 expected = F * f.P * F.transpose() + Q;
  EXPECT_LT((p.P - expected).norm(), 1e-13 * expected.norm());
  EXPECT_LT((p.P - p.P.transpose()).norm(), 1e-15 * expected.norm());
}

TEST(PoseFilter, AtRestHasThePoseCovarianceAndTheRatesAPrioriSpread) {
  Transform T = Transform::Identity();
  T.translation() = Vec3(0.2, 0.1, 0.3);
  const Mat6 pose_cov = random_spd(3).topLeftCorner<6, 6>();
  const PoseFilter f = PoseFilter::at_rest(2.0, T, pose_cov, 0.5, 4.0);
  EXPECT_TRUE(f.valid);
  EXPECT_EQ(f.t_s, 2.0);
  EXPECT_TRUE(f.T_w_b.isApprox(T, 0.0));
  EXPECT_EQ(f.omega_w, Vec3::Zero());
  EXPECT_EQ(f.v_w, Vec3::Zero());
  Mat12 expected = Mat12::Zero();
  expected.topLeftCorner<6, 6>() = pose_cov;
  expected.block<3, 3>(6, 6) = 0.25 * Mat3::Identity();
  expected.block<3, 3>(9, 9) = 16.0 * Mat3::Identity();
  EXPECT_EQ(f.P, expected);
}

TEST(BodyMotion, KeepsTheLastTwoSolvedPosesInOrderAndForgetsEverythingOnReset) {
  BodyMotion motion;
  EXPECT_FALSE(motion.last_solved.valid);
  EXPECT_FALSE(motion.previous_solved.valid);
  for (int k = 0; k < 3; ++k) {
    pose::PoseResult r;
    r.valid = true;
    r.T.translation() = Vec3(k, 0, 0);
    r.loadings.setConstant(6, 4, k);
    motion.record_solved(100 + k, r);
  }
  EXPECT_TRUE(motion.last_solved.valid);
  EXPECT_EQ(motion.last_solved.t_ns, 102);
  EXPECT_EQ(motion.last_solved.pose.T.translation().x(), 2.0);
  EXPECT_EQ(motion.last_solved.pose.loadings(5, 3), 2.0);
  EXPECT_TRUE(motion.previous_solved.valid);
  EXPECT_EQ(motion.previous_solved.t_ns, 101);
  EXPECT_EQ(motion.previous_solved.pose.T.translation().x(), 1.0);
  EXPECT_EQ(motion.previous_solved.pose.loadings(0, 0), 1.0);

  motion.filter = PoseFilter::at_rest(1.0, Transform::Identity(), Mat6::Identity(), 1, 1);
  motion.last_world = {true, 102, Transform::Identity()};
  motion.first_motion_ns = 101;
  motion.reset();
  EXPECT_FALSE(motion.filter.valid);
  EXPECT_FALSE(motion.last_world.valid);
  EXPECT_FALSE(motion.last_solved.valid);
  EXPECT_FALSE(motion.previous_solved.valid);
  EXPECT_EQ(motion.first_motion_ns, std::numeric_limits<time::TaiNs>::min());
}

// The resection's start: the last solved world pose within its age on either side, none
// without a time or a pose.
TEST(BodyMotion, RecentWorldPoseOnlyWithinItsAge) {
  BodyMotion motion;
  constexpr time::TaiNs kSolvedNs = 5'000'000'000;
  EXPECT_FALSE(motion.recent_world_pose(kSolvedNs, 1.0).has_value());
  Transform T = Transform::Identity();
  T.translation() = Vec3(0.1, 0.2, 0.3);
  motion.last_world = {true, kSolvedNs, T};
  const double max_age_s = 0.0201;
  for (const time::TaiNs age_ns : {0, 20'000'000, -20'000'000}) {
    const auto pose = motion.recent_world_pose(kSolvedNs + age_ns, max_age_s);
    ASSERT_TRUE(pose.has_value()) << age_ns;
    EXPECT_TRUE(pose->isApprox(T, 0.0));
  }
  for (const time::TaiNs age_ns : {20'200'000, -20'200'000})
    EXPECT_FALSE(motion.recent_world_pose(kSolvedNs + age_ns, max_age_s).has_value()) << age_ns;
  EXPECT_FALSE(motion.recent_world_pose(std::numeric_limits<time::TaiNs>::min(), 1e9).has_value());
}

}  // namespace
}  // namespace storetrack::match
