// SisTrO's dynamic calibration (docs/evaluation.md, "Pendulum"): a pendulum board carrying
// marks swings in a plane about a pivot; its angle obeys
//   m l2^2 theta'' + beta theta' + m g l1 sin(theta) = 0   (theta = 0: centre of mass below),
// from rest at theta0 until the release time t0. From the measured 3-D mark trajectories of one
// or several runs the identification (Ceres) recovers what the kinematics determine:
//   L = l2^2 / l1 (the equivalent simple-pendulum length, omega0^2 = g / L),
//   gamma = beta / (m l2^2) (damping per unit inertia),
//   per run theta0 and t0, the plane's normal n and the pivot c in the world frame, and per mark
//   its radius r, its angle phi from the centre-of-mass line and its offset h along n.
// l1 and l2 separately (and beta / m) need l1 from elsewhere (a balance; --l1). The reference
// trajectory from the identified model gives the dynamic error (measured - reference) per axis.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "storetrack/eval/marks_csv.hpp"
#include "storetrack/geometry/transform.hpp"

namespace storetrack::eval {

/// The parameter covariance, from A = J^T W J (residuals whitened by the stated covariance).
enum class CovarianceScale {
  kObserved,  ///< sandwich A^-1 B A^-1, B from the residuals per exposure (default, see .md)
  kResidual,  ///< s^2 A^-1, s^2 = chi^2 / (n - p): assumes the stated covariance's shape
  kStated,    ///< A^-1: trusts the host's stated covariance as independent errors
};

struct PendulumOptions {
  char body = 's';          ///< marks of this body are the pendulum's (the host tracks it as store)
  double g_m_s2 = 9.80665;  ///< local gravity
  geometry::Vec3 down_w = geometry::Vec3(0, 0, 1);  ///< gravity direction, world frame (z down)
  std::optional<double> l1_m;                       ///< pivot-to-centre-of-mass distance, if known
  double l1_sigma_m = 0;
  CovarianceScale covariance_scale = CovarianceScale::kObserved;
  int min_exposures_after_release = 40;           ///< a shorter run cannot be identified
  std::optional<geometry::Transform> T_w_camera;  ///< reference camera, for the axis distance
  int distance_bins = 5, speed_bins = 5;
};

/// One run: the samples of one recording (one release), times relative to its first sample.
struct PendulumRun {
  std::string path;
  std::int64_t origin_tai_ns = 0;  ///< reference_mid_tai_ns of the first sample
  std::vector<MarkSample> samples;
  std::int64_t other_body_samples = 0;  ///< samples of other bodies (counted, not used)
  std::int64_t excluded_rows = 0;       ///< rows the host flagged excluded (counted, not used)
};

/// The estimated parameters with their standard uncertainties (1 sigma).
struct PendulumRunEstimate {
  std::string path;
  double theta0_rad = 0, theta0_sigma_rad = 0;
  double release_s = 0, release_sigma_s = 0;  ///< after the run's first sample
  std::int64_t release_tai_ns = 0;
  bool clockwise = true;  ///< theta decreasing about n (n is oriented so run 0 is clockwise)
  int exposures = 0, exposures_after_release = 0;
  double rms_residual_m = 0;
};

struct PendulumMarkEstimate {
  int mark_id = 0;
  double radius_m = 0, radius_sigma_m = 0;
  double angle_rad = 0, angle_sigma_rad = 0;  ///< from the centre-of-mass line, about n
  double offset_m = 0, offset_sigma_m = 0;    ///< along n; 0 by definition for the first mark
};

/// Dynamic error statistics of one group of samples, per world axis.
struct DynamicAxis {
  double mean_m = 0;         ///< mean of measured - reference
  double sd_m = 0;           ///< its standard deviation: SisTrO's dynamic uncertainty (1 sigma)
  double u_reference_m = 0;  ///< RMS of the reference's own u (parameter covariance)
  double u_stated_m = 0;     ///< RMS of the host's stated per-sample u
};

struct DynamicBin {
  double low = 0, high = 0;  ///< bin edges (m, or m/s)
  int samples = 0;
  std::array<double, 3> rms_m{};  ///< RMS dynamic error per axis
};

struct PendulumResult {
  PendulumOptions options;
  // Shared model parameters.
  double equivalent_length_m = 0, equivalent_length_sigma_m = 0;          ///< L = l2^2 / l1
  double damping_per_inertia_1_s = 0, damping_per_inertia_sigma_1_s = 0;  ///< beta/(m l2^2)
  double omega0_rad_s = 0;
  std::optional<double> l2_m, l2_sigma_m, beta_per_mass_m2_s, beta_per_mass_sigma_m2_s;
  geometry::Vec3 pivot_w = geometry::Vec3::Zero();
  Eigen::Matrix3d pivot_covariance = Eigen::Matrix3d::Zero();
  geometry::Vec3 normal_w = geometry::Vec3::UnitZ();
  double normal_sigma_rad = 0;  ///< RMS tilt uncertainty of n (root of the covariance trace)
  std::vector<PendulumRunEstimate> runs;
  std::vector<PendulumMarkEstimate> marks;
  // Fit quality.
  int residuals = 0, parameters = 0;
  double reduced_chi_square = 0;  ///< chi^2 / (n - p) with the stated u
  int solver_iterations = 0;
  // Dynamic error (measured - reference), SisTrO's dynamic table.
  std::array<DynamicAxis, 3> dynamic{};
  std::array<DynamicAxis, 3> dynamic_clockwise{}, dynamic_counter_clockwise{};
  int samples_clockwise = 0, samples_counter_clockwise = 0;
  std::array<double, 3> model_error_m{};     ///< mean(cw) - mean(ccw); NaN without both directions
  std::array<double, 3> model_error_u_m{};   ///< its standard uncertainty
  std::vector<DynamicBin> by_axis_distance;  ///< empty without T_w_camera
  std::vector<DynamicBin> by_speed;
  std::int64_t other_body_samples = 0, excluded_rows = 0;
};

/// The samples of `options.body` from each recording, as runs; throws EvalInputError when a
/// recording has no reference_mid_tai_ns column or no sample of the body.
std::vector<PendulumRun> pendulum_runs(const std::vector<MarksRecording>& recordings,
                                       const PendulumOptions& options);

/// Identifies the model from the runs; throws EvalInputError naming the file when a run is too
/// short to identify (no release seen, too few exposures after it, fewer than 3 marks).
PendulumResult identify_pendulum(const std::vector<PendulumRun>& runs,
                                 const PendulumOptions& options = {});

/// The pendulum angle and rate from rest at theta0 (t <= 0: held) for an angular frequency
/// omega0^2 = g / L and damping gamma: RK4 on a fixed step, a partial step to each time.
/// `times_s` ascending. Exposed for the tests (checked against closed forms).
void pendulum_angles(double omega0_sq, double gamma, double theta0,
                     const std::vector<double>& times_s, std::vector<double>& theta,
                     std::vector<double>& theta_dot);

}  // namespace storetrack::eval
