// PoseTracker: constant-velocity extrapolation of the store pose T_p_s over short gaps in the
// store marks (FtiSample status bit "extrapolated", common/msg/schema/fti_sample.yaml), with an
// honest covariance (docs/uncertainty.md, "Extrapolation").
//
// The ExposureProcessor solves each exposure on its own and calls update() with the store's
// motion state (match::BodyMotion, the matcher's: the one motion state of the body), which
// keeps the last two solved poses. When an exposure has no solved T_p_s (fewer than 3
// non-collinear store marks, or no pylon frame) and the last solved pose is at most `max_gap_s`
// old, the sample carries the constant-velocity prediction (translation and rotation) with
// status valid | extrapolated; beyond the gap the sample stays invalid. The prediction's
// covariance is first-order: the two poses' calibration errors are the same factors (loadings
// combine, they largely cancel in the velocity), their centroid errors are independent, the
// survey error is common, and the store's relative acceleration over the gap, a random
// constant with the stated mean (mean_accel_p_m_s2, gravity for a released store) and per-axis
// spread (accel_sigma_m_s2, angular_accel_sigma_rad_s2), adds its mean to the prediction and its
// spread as process noise. Until the store is known to fly free (the captive store, the
// release, the ejector stroke) the acceleration is anywhere in the ejector's stated bound
// instead (docs/uncertainty.md, "Release zone").
#pragma once

#include <cstdint>
#include <limits>

#include "storetrack/match/body_motion.hpp"
#include "storetrack/pipeline/exposure_result.hpp"

namespace storetrack::pipeline {

struct PoseTrackerConfig {
  /// Longest extrapolation after the last solved pose [s]; older tracks give invalid samples.
  double max_gap_s = 0.02;
  /// The two solved poses that give the velocity must be at most this far apart [s].
  double max_velocity_baseline_s = 0.05;
  /// Process model (docs/uncertainty.md, "Extrapolation"): over the gap the store's
  /// acceleration relative to the pylon is a random constant, mean `mean_accel_p_m_s2` and
  /// standard uncertainty `accel_sigma_m_s2` per pylon axis. A released store falls relative
  /// to the aircraft with the aircraft's specific force reversed: +n_z g along z_p (down) at
  /// load factor n_z (default 1 g, standard gravity); set n_z g of the test point, or 0 for a
  /// captive store. The spread is the store's own aerodynamic specific force (drag, lift, side
  /// force: a few m/s^2 for a 250 kg store at 30 kPa) plus the load-factor tolerance.
  geometry::Vec3 mean_accel_p_m_s2 = geometry::Vec3(0, 0, 9.80665);
  double accel_sigma_m_s2 = 5.0;
  /// Standard uncertainty per axis of the store's angular acceleration relative to the pylon
  /// [rad/s^2] (mean 0): aerodynamic pitching and yawing moments after release.
  double angular_accel_sigma_rad_s2 = 2.0;
  /// Release and ejector stroke (docs/uncertainty.md, "Release zone"): until the store has been
  /// in free flight, its relative acceleration along z_p lies anywhere between 0 (captive) and
  /// the release unit's peak `ejector_accel_max_m_s2`, and its angular acceleration anywhere
  /// within +-`ejector_angular_accel_max_rad_s2` (the ejector's pitching moment). Free flight
  /// begins `ejector_duration_max_s` after the store's first significant motion (its velocity
  /// along z_p above 5 standard uncertainties of its centroid part). Defaults: a 10 g ejector
  /// peak over at most 80 ms, above common release units' strokes (30-60 ms).
  double ejector_accel_max_m_s2 = 100.0;
  double ejector_angular_accel_max_rad_s2 = 20.0;
  double ejector_duration_max_s = 0.08;
};

struct PoseTrackerCounters {
  std::uint64_t solved = 0;            ///< exposures with a solved T_p_s (track updated)
  std::uint64_t extrapolated = 0;      ///< samples predicted from the track
  std::uint64_t not_extrapolated = 0;  ///< unsolved and no usable track (gap, no velocity)
  std::uint64_t extrapolated_in_release_zone = 0;  ///< of `extrapolated`: with the ejector's model
};

class PoseTracker {
 public:
  /// `factors`: the processor's (ExposureProcessor::factors()), to split the prediction's
  /// calibration covariance by source.
  explicit PoseTracker(const uncertainty::CalibrationFactors& factors,
                       const PoseTrackerConfig& config = {});

  /// Call once per exposure, in time order, with the exposure's solution and the store's
  /// motion state (the ExposureProcessor calls it before it writes the sample). A solved T_p_s
  /// is recorded in the motion state. An unsolved one is replaced, when the motion state
  /// allows, by the prediction: result.extrapolated, T_p_s_extrapolated,
  /// cov_T_p_s_extrapolated, xyz_ypr and cov_xyz_ypr(_by_source); the processor's sample then
  /// carries it with status kValid | kExtrapolated. Returns true when it extrapolated.
  bool update(ExposureResult& result, match::BodyMotion& store);

  const PoseTrackerCounters& counters() const { return counters_; }
  const PoseTrackerConfig& config() const { return config_; }

 private:
  uncertainty::CalibrationFactors factors_;
  PoseTrackerConfig config_;
  /// Velocity along z_p of the last two solved poses above 5 sigma: the store moves away.
  bool moving_away(const match::SolvedPose& last, const match::SolvedPose& previous) const;
  /// Mean and standard uncertainty per pylon axis of the relative acceleration over a gap
  /// ending at `t_ns` (the release zone's, or free flight's).
  struct Acceleration {
    geometry::Vec3 mean;
    geometry::Vec3 sigma;
    double angular_sigma;
    bool release_zone;
  };
  Acceleration acceleration_at(time::TaiNs t_ns, time::TaiNs first_motion_ns) const;

  PoseTrackerCounters counters_;
};

}  // namespace storetrack::pipeline
