// Release time t0 of the store from the data (issue 26): the first motion of the store relative
// to the pylon, with its standard uncertainty (docs/post-processing.md, "Release time").
//
// 1. Detection (Basseville, Nikiforov, "Detection of Abrupt Changes", Prentice Hall 1993, 2.4:
//    chi-square test of a change in the mean): the captive hypothesis is a constant store
//    position; its reference is the weighted mean of the first solved exposures. Each later
//    exposure's displacement from it is tested against its covariance (noise of both, and the
//    change of the shared calibration/survey error between them), chi-square with 3 degrees of
//    freedom above its (1 - false_alarm) quantile: the alarm.
// 2. Estimation: the ejector accelerates the store uniformly from t0, so around the alarm
//    p(t) = c + a max(0, t - t0)^2 / 2 (segmented regression with a smooth join: the model is
//    continuously differentiable in t0; G. A. F. Seber, C. J. Wild, "Nonlinear Regression",
//    Wiley 1989, 9.3, and P. I. Feder, Annals of Statistics 3(1) 1975: the least-squares t0 is
//    asymptotically normal with the usual information-matrix covariance). The weight W is the
//    inverse of the points' joint covariance, noise plus shared loadings: exposures solved from
//    different cameras (observations lost live) carry different shared errors (issue 26).
//    c and a enter linearly: t0 minimises the profile chi-square. u(t0): (J^T W J)^-1, split
//    by the estimate's linear map into the noise and the shared part (a constant shared error
//    is absorbed by c: none on t0).
//    No t0 when it falls inside the captive reference, or when the fit's chi-square exceeds its
//    (1 - false_alarm) quantile (the model does not explain the data: u(t0) would not hold).
#pragma once

#include <span>
#include <string>

#include "storetrack/smooth/pose_smoother.hpp"

namespace storetrack::smooth {

struct ReleaseTimeConfig {
  /// The first solved exposures within this time form the captive reference [s]; the recording
  /// must start at least this long before the release.
  double captive_reference_s = 0.005;
  /// Probability per captive exposure that the test alarms on noise alone.
  double false_alarm = 1e-6;
  /// Data before the alarm in the onset fit, and the range searched for t0 [s].
  double lookback_s = 0.02;
  /// Data after the alarm in the onset fit [s]: inside the ejector's stroke (50 ms), where the
  /// acceleration is uniform.
  double onset_window_s = 0.01;
};

struct ReleaseTime {
  bool detected = false;
  std::string reason;  ///< why not, when not detected
  time::TaiNs t0_ns = 0;
  double u_t0_s = 0;         ///< total standard uncertainty (k = 1)
  double u_noise_s = 0;      ///< the centroid-noise part
  double u_shared_s = 0;     ///< the calibration and survey part
  time::TaiNs alarm_ns = 0;  ///< the first exposure the captive test rejected
  double alarm_chi2 = 0, alarm_threshold = 0;
  geometry::Vec3 onset_accel_p = geometry::Vec3::Zero();  ///< a of the fit [m/s^2]
  double fit_chi2 = 0;  ///< of the onset fit (joint covariance), with fit_dof degrees of freedom
  int fit_dof = 0;
};

/// t0 from the solved poses of `measurements` (time order).
ReleaseTime estimate_release_time(std::span<const PoseMeasurement> measurements,
                                  const ReleaseTimeConfig& config = {});

}  // namespace storetrack::smooth
