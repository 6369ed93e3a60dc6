// Fixed-interval smoother of the store pose T_p_s (issue 26): the best estimate of the store's
// trajectory relative to the pylon over each tracked segment of a recording, with its
// velocity, acceleration and angular rate, each with an honest covariance split in two parts
// (docs/post-processing.md, "Smoothed trajectory"):
// - the noise part: errors independent from exposure to exposure (centroid noise) and the
//   model's process noise, which the smoother averages (Rauch, Tung, Striebel 1965);
// - the shared part: calibration (intrinsic, extrinsic, time offsets) and survey errors, ONE
//   draw for the whole recording, which smoothing cannot average away. Each exposure states
//   them as loadings on the same whitened factors; the smoother is linear in its measurements,
//   so its shared error is the same linear combination of the exposures' loadings, propagated
//   exactly (to first order) however the loadings vary along the trajectory.
//
// Model (Bar-Shalom, Li, Kirubarajan 2001, "Estimation with Applications to Tracking and
// Navigation", 6.2.3): constant acceleration with continuous white-noise jerk (CWPA), per pylon
// axis, for the position and for the attitude (constant angular acceleration, white angular
// jerk). The attitude state is a small rotation vector about the exposures' own solved
// attitudes (left perturbation, docs/conventions.md): theta_k accumulates Log(R_k+1 R_k^T) of
// the solved attitudes, so the filter is linear; the smoothed attitude is
// Exp(theta_hat_k - theta_k) R_k. The white jerk is the aerodynamic forces' slow change; the
// ejector's start and end are steps of the acceleration, which the filter detects from its
// innovations and models as a jump in the interval where it happened (Bar-Shalom 2001, 11.2:
// process noise adjusted on a detected manoeuvre; the jump's covariance, for a step at a
// uniformly distributed instant of the interval, is the CWPA Q with q = step^2 / T).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "storetrack/geometry/transform.hpp"
#include "storetrack/pipeline/exposure_result.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::smooth {

/// The smoother's state, in this order: attitude (left rotation vector, pylon frame) and
/// position (the pose perturbation's order, docs/conventions.md), angular rate, velocity,
/// angular acceleration, acceleration (all in the pylon frame).
inline constexpr int kStateSize = 18;
inline constexpr int kAttitude = 0, kPosition = 3, kAngularRate = 6, kVelocity = 9,
                     kAngularAccel = 12, kAcceleration = 15;
using StateVector = Eigen::Matrix<double, kStateSize, 1>;
using StateMatrix = Eigen::Matrix<double, kStateSize, kStateSize>;
/// Loadings on the shared errors' whitened factors (rows: pose perturbation or state).
using SharedLoadings6 = Eigen::Matrix<double, 6, Eigen::Dynamic>;
using SharedLoadings = Eigen::Matrix<double, kStateSize, Eigen::Dynamic>;

/// One exposure of the recording as the smoother sees it.
struct PoseMeasurement {
  time::TaiNs t_ns = 0;  ///< the exposure's reference mid-time
  bool solved = false;   ///< false: no T_p_s (the smoother predicts through it)
  geometry::Transform T_p_s = geometry::Transform::Identity();
  /// Covariance of the errors independent between exposures (left perturbation (r, t)).
  geometry::Mat6 cov_noise = geometry::Mat6::Zero();
  /// Loadings on the errors shared by the whole recording: the calibration factors' columns,
  /// then the survey's (the same columns in every exposure of one recording).
  SharedLoadings6 shared;
  /// The pylon's pose in the aircraft (the rig's world) frame at this exposure, for the data
  /// product's aircraft axes (the smoother does not use it): its noise (centroid) covariance and
  /// its loadings on the same shared factors, in the same columns as `shared`.
  bool pylon_solved = false;
  geometry::Transform T_w_p = geometry::Transform::Identity();
  geometry::Mat6 pylon_cov_noise = geometry::Mat6::Zero();
  SharedLoadings6 pylon_shared;
};

/// The processor's solution of one exposure: noise = the centroid source; shared = the
/// calibration loadings (intrinsic, extrinsic, sync) and the survey loadings. An extrapolated or
/// unsolved pose is not a measurement (solved = false).
PoseMeasurement measurement_from(const pipeline::ExposureResult& r);

struct SmootherConfig {
  /// Exposures further apart than this without a solved pose end a segment [s].
  double max_gap_s = 0.02;
  /// Process noise, derived (docs/post-processing.md, "Process noise"): the store's
  /// aerodynamic specific force, spread `aero_accel_sigma_m_s2` per axis about its mean (the
  /// PoseTracker's envelope, docs/uncertainty.md), changes as the store crosses the pylon's
  /// flow field, over `flow_field_time_s`: a random walk of the acceleration reaching that
  /// spread over that time, white jerk of PSD q = sigma^2 / tau (Bar-Shalom 2001, 6.2.3).
  double aero_accel_sigma_m_s2 = 5.0;
  double aero_angular_accel_sigma_rad_s2 = 2.0;
  double flow_field_time_s = 0.4;
  /// The ejector's steps of the acceleration (start and end of the stroke): 2 stroke /
  /// duration^2 (0.1 m in 50 ms: 80 m/s^2), and of the angular acceleration: the rate it gives
  /// over the stroke / duration (0.6 rad/s in 50 ms: 12 rad/s^2). A step is detected when the
  /// innovation's chi-square exceeds its (1 - step_false_alarm) quantile; the jump is then
  /// modelled in the two intervals before that exposure (the step lies in one of them).
  double accel_step_m_s2 = 80.0;
  double angular_accel_step_rad_s2 = 12.0;
  double step_false_alarm = 1e-4;
  /// Prior standard deviations of the rates at a segment's first exposure: the envelope of a
  /// store relative to its pylon over the measured volume, wide beside what three exposures
  /// determine (velocity to ~0.01 m/s, acceleration to ~10 m/s^2), so the data decide; not
  /// diffuse, which costs the backward pass its precision (its gains are taken through the
  /// inverse of the predicted covariance).
  double prior_angular_rate_rad_s = 10.0;
  double prior_velocity_m_s = 20.0;
  double prior_angular_accel_rad_s2 = 100.0;
  double prior_accel_m_s2 = 200.0;
};

/// The smoothed state at one exposure of a segment.
struct SmoothedState {
  time::TaiNs t_ns = 0;
  int segment = 0;        ///< index of the tracked segment
  bool measured = false;  ///< the exposure had a solved pose
  geometry::Transform T_p_s = geometry::Transform::Identity();
  geometry::Vec3 angular_rate_p = geometry::Vec3::Zero();   ///< [rad/s], pylon frame
  geometry::Vec3 velocity_p = geometry::Vec3::Zero();       ///< [m/s]
  geometry::Vec3 angular_accel_p = geometry::Vec3::Zero();  ///< [rad/s^2]
  geometry::Vec3 accel_p = geometry::Vec3::Zero();          ///< [m/s^2]
  bool step = false;  ///< an acceleration step was modelled in the interval before this one
  StateMatrix cov_noise = StateMatrix::Zero();  ///< averaged part (noise and process noise)
  /// Loadings on the recording's shared factors: the shared part (calibration + survey, not
  /// averaged) is shared shared^T; they let the data product combine states of different times
  /// and its own shared errors (the CG's). Not stored as a covariance too: the states of a long
  /// segment are the smoother's memory (docs/performance.md, "Smoother memory").
  SharedLoadings shared;
  /// The per-exposure solution's noise covariance (zero when not measured), for comparison.
  geometry::Mat6 cov_noise_per_exposure = geometry::Mat6::Zero();
  StateMatrix cov_shared() const { return shared * shared.transpose(); }
  StateMatrix cov() const { return cov_noise + cov_shared(); }
};

struct SmootherCounters {
  std::uint64_t segments = 0;
  std::uint64_t measurements = 0;     ///< solved poses used
  std::uint64_t predicted = 0;        ///< exposures inside a segment without a solved pose
  std::uint64_t left_out = 0;         ///< unsolved exposures outside any segment
  std::uint64_t update_failures = 0;  ///< innovation covariance not positive definite (skipped)
  std::uint64_t steps = 0;            ///< intervals modelled with an acceleration step
};

/// Smooths `measurements` (in time order). Returns one state per exposure inside a segment (a
/// segment starts and ends with a solved pose and has no gap longer than max_gap_s);
/// segments of a single solved pose are left out (no rate).
std::vector<SmoothedState> smooth_trajectory(std::span<const PoseMeasurement> measurements,
                                             const SmootherConfig& config,
                                             SmootherCounters* counters = nullptr);

/// The process model of one interval dt: transition F and process covariance Q of white jerk
/// and white angular jerk of the given PSDs (exposed for the tests' closed forms).
void process_model(double dt, double jerk_psd, double angular_jerk_psd, StateMatrix& F,
                   StateMatrix& Q);

}  // namespace storetrack::smooth
