#include "storetrack/pipeline/pose_tracker.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>

#include "sample_fields.hpp"

namespace storetrack::pipeline {

using geometry::Mat3;
using geometry::Mat6;
using geometry::Transform;
using geometry::Vec3;
using uncertainty::Source;

PoseTracker::PoseTracker(const uncertainty::CalibrationFactors& factors,
                         const PoseTrackerConfig& config)
    : factors_(factors), config_(config) {
  if (!(config_.max_gap_s >= 0) || !std::isfinite(config_.max_gap_s))
    throw std::invalid_argument("PoseTracker: max_gap_s must be finite and >= 0");
  if (!(config_.max_velocity_baseline_s > 0) || !std::isfinite(config_.max_velocity_baseline_s))
    throw std::invalid_argument("PoseTracker: max_velocity_baseline_s must be finite and > 0");
  if (!(config_.accel_sigma_m_s2 >= 0) || !std::isfinite(config_.accel_sigma_m_s2) ||
      !(config_.angular_accel_sigma_rad_s2 >= 0) ||
      !std::isfinite(config_.angular_accel_sigma_rad_s2))
    throw std::invalid_argument("PoseTracker: process noise sigmas must be finite and >= 0");
  if (!config_.mean_accel_p_m_s2.allFinite())
    throw std::invalid_argument("PoseTracker: mean_accel_p_m_s2 must be finite");
  if (!(config_.ejector_accel_max_m_s2 >= 0) || !std::isfinite(config_.ejector_accel_max_m_s2) ||
      !(config_.ejector_angular_accel_max_rad_s2 >= 0) ||
      !std::isfinite(config_.ejector_angular_accel_max_rad_s2) ||
      !(config_.ejector_duration_max_s >= 0) || !std::isfinite(config_.ejector_duration_max_s))
    throw std::invalid_argument("PoseTracker: the ejector's bounds must be finite and >= 0");
}

bool PoseTracker::moving_away(const match::SolvedPose& last,
                              const match::SolvedPose& previous) const {
  const double dt = static_cast<double>(last.t_ns - previous.t_ns) * 1e-9;
  if (!last.valid || !previous.valid || !(dt > 0) || dt > config_.max_velocity_baseline_s)
    return false;
  // z_p of each pose from its left perturbation: dp = -[p]x d_theta + d_t. The calibration
  // error is common to both poses and cancels in the velocity: the centroid parts remain.
  const auto i_cent = static_cast<size_t>(uncertainty::index(Source::kCentroid));
  auto var_z = [&](const match::SolvedPose& s) {
    Eigen::Matrix<double, 1, 6> J;
    const Vec3 p = s.pose.T.translation();
    J << p.y(), -p.x(), 0, 0, 0, 1;  // row z of [-[p]x, I]
    return (J * s.pose.cov_by_source[i_cent] * J.transpose())(0, 0);
  };
  const double v_z = (last.pose.T.translation().z() - previous.pose.T.translation().z()) / dt;
  const double u_v_z = std::sqrt(var_z(last) + var_z(previous)) / dt;
  return v_z > 5.0 * u_v_z;  // a false start on a captive store: 3e-7 per exposure
}

PoseTracker::Acceleration PoseTracker::acceleration_at(time::TaiNs t_ns,
                                                       time::TaiNs first_motion_ns) const {
  const double aero = config_.accel_sigma_m_s2;
  const bool free_flight =
      first_motion_ns != std::numeric_limits<time::TaiNs>::min() &&
      static_cast<double>(t_ns - first_motion_ns) * 1e-9 > config_.ejector_duration_max_s;
  if (free_flight)
    return {config_.mean_accel_p_m_s2, Vec3::Constant(aero), config_.angular_accel_sigma_rad_s2,
            false};
  // Anywhere in [0, a_max] along z_p: the bound's midpoint as the mean and its half-width as one
  // standard uncertainty, so a k = 2 interval keeps >= 95 % coverage wherever in the bound the
  // true value lies (docs/uncertainty.md, "Release zone"); the same for the angular bound.
  const double half = 0.5 * config_.ejector_accel_max_m_s2;
  return {Vec3(0, 0, half), Vec3(aero, aero, std::hypot(half, aero)),
          std::max(config_.angular_accel_sigma_rad_s2, config_.ejector_angular_accel_max_rad_s2),
          true};
}

bool PoseTracker::update(ExposureResult& r, match::BodyMotion& store) {
  r.extrapolated = false;
  const time::TaiNs t = r.reference_mid_tai_ns;
  const match::SolvedPose& last = store.last_solved;
  const match::SolvedPose& previous = store.previous_solved;
  if (r.T_p_s.valid) {
    ++counters_.solved;
    // The velocity pair is the last two solved poses, if close enough in time.
    store.record_solved(t, r.T_p_s);
    if (store.first_motion_ns == std::numeric_limits<time::TaiNs>::min() &&
        moving_away(last, previous))
      store.first_motion_ns = t;
    return false;
  }
  const bool no_time = t == std::numeric_limits<time::TaiNs>::min();
  const double tau = static_cast<double>(t - last.t_ns) * 1e-9;             // horizon
  const double dt = static_cast<double>(last.t_ns - previous.t_ns) * 1e-9;  // baseline
  if (no_time || !last.valid || !previous.valid || !(tau > 0) || tau > config_.max_gap_s ||
      !(dt > 0) || dt > config_.max_velocity_baseline_s) {
    ++counters_.not_extrapolated;
    return false;
  }

  // Velocity from differencing: v = (t1 - t0) / dt, omega dt = Log(R1 R0^T) (left/spatial
  // increments, docs/conventions.md). The differenced velocity belongs to t1 - dt / 2, so a
  // constant acceleration alpha moves the pose by alpha tau (tau + dt) / 2 beyond the
  // constant-velocity extrapolation at tau after the last solved pose.
  const Transform& T1 = last.pose.T;
  const Transform& T0 = previous.pose.T;
  const double a = tau / dt;
  const double lever = 0.5 * tau * (tau + dt);
  const Acceleration accel = acceleration_at(t, store.first_motion_ns);
  const Vec3 rot_step = geometry::rotvec_from_rotation(T1.linear() * T0.linear().transpose());
  Transform T_pred = Transform::Identity();
  T_pred.linear() = geometry::rotation_from_rotvec(a * rot_step) * T1.linear();
  T_pred.translation() =
      T1.translation() + a * (T1.translation() - T0.translation()) + lever * accel.mean;

  // First order (the rotation between the two poses and over tau is small, so Exp's Jacobian
  // and the adjoint of Exp(omega tau) are I to first order): xi_pred = (1 + a) xi_1 - a xi_0.
  std::array<Mat6, uncertainty::kNumSources> by_source{};
  const PoseResult& p1 = last.pose;
  const PoseResult& p0 = previous.pose;
  const double w1 = 1.0 + a, w0 = -a;
  const auto i_cent = static_cast<size_t>(uncertainty::index(Source::kCentroid));
  const auto i_surv = static_cast<size_t>(uncertainty::index(Source::kSurvey));
  // Centroid noise: independent between exposures.
  by_source[i_cent] = w1 * w1 * p1.cov_by_source[i_cent] + w0 * w0 * p0.cov_by_source[i_cent];
  // Survey: the same survey errors move both poses alike (w1 + w0 = 1): the last pose's part.
  by_source[i_surv] = p1.cov_by_source[i_surv];
  const int nz = factors_.num_factors();
  const bool have_loadings = p1.loadings.cols() == nz && p0.loadings.cols() == nz;
  // Common calibration factors: the loadings combine (their errors largely cancel in the
  // velocity and the prediction keeps the last pose's calibration error).
  const uncertainty::Loadings6 L = have_loadings
                                       ? uncertainty::Loadings6(w1 * p1.loadings + w0 * p0.loadings)
                                       : uncertainty::Loadings6();
  for (Source src : {Source::kIntrinsic, Source::kExtrinsic, Source::kSync}) {
    const auto i = static_cast<size_t>(uncertainty::index(src));
    if (have_loadings) {
      by_source[i] = uncertainty::covariance_of(L, factors_, src);
    } else {
      // No loadings (poses from another processor): correlation unknown; the bound
      // cov(w1 x1 + w0 x0) <= 2 w1^2 C1 + 2 w0^2 C0 holds whatever it is.
      by_source[i] = 2.0 * (w1 * w1 * p1.cov_by_source[i] + w0 * w0 * p0.cov_by_source[i]);
    }
  }
  // Process noise: the acceleration's spread about its mean through the same lever.
  // A budget source of its own, so the sample's budget adds up to its total.
  Mat6& process = by_source[static_cast<size_t>(uncertainty::index(Source::kProcess))];
  process.setZero();
  process.topLeftCorner<3, 3>() = Mat3::Identity() * std::pow(accel.angular_sigma * lever, 2);
  process.bottomRightCorner<3, 3>() = (accel.sigma * lever).array().square().matrix().asDiagonal();
  Mat6 cov = Mat6::Zero();
  for (const Mat6& c : by_source)
    cov += c;

  r.extrapolated = true;
  r.T_p_s_extrapolated = T_pred;
  r.cov_T_p_s_extrapolated = cov;
  r.extrapolation_horizon_s = tau;
  r.xyz_ypr = xyz_ypr(T_pred);
  const Mat6 J = output_jacobian(T_pred);
  r.cov_xyz_ypr = J * cov * J.transpose();
  for (size_t s = 0; s < by_source.size(); ++s)
    r.cov_xyz_ypr_by_source[s] = J * by_source[s] * J.transpose();
  ++counters_.extrapolated;
  counters_.extrapolated_in_release_zone += accel.release_zone;
  return true;
}

}  // namespace storetrack::pipeline
