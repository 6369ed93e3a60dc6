// Calibration health: a sequential test per camera that its extrinsic calibration still holds,
// on the reprojection residuals of the pylon marks (docs/calibration-health.md derives the
// test, its false-alarm rate and its detection delay).
//
// The cameras ride on the pylon, so its marks are static in the rig's world frame: each is
// predicted once, u_i = pi_c(T_ref q_i) with T_ref the first solved T_w_p. The calibration
// error, the survey error and T_ref's own error are then one constant bias per (camera, mark),
// estimated as its mean residual over a baseline; what is tested is the CHANGE of the mean
// residual in disjoint windows of W exposures against that baseline, d_i, whose covariance is
// centroid noise alone: v_i I, v_i = 1/sum_W(1/s^2) + 1/sum_B(1/s^2). A camera motion xi (left
// perturbation of T_c_w) moves d_i by J_i xi; its generalised least-squares estimate from the
// camera's marks, xi = A^-1 g (A = sum J_i^T J_i / v_i, g = sum J_i^T d_i / v_i), has
// covariance A^-1, and T = g^T A^-1 g ~ chi-square(6) while the camera holds: alarm above the
// chi-square(6) quantile at 1 - alpha.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/pipeline/aligned_exposure.hpp"
#include "storetrack/pipeline/exposure_result.hpp"
#include "storetrack/survey/survey.hpp"

namespace storetrack::pipeline {

struct CalibrationHealthConfig {
  int window_exposures = 40;  ///< W: one test per camera every W exposures
  /// The baseline spans baseline_windows * W exposures; windows share its error, correlation
  /// 1 / (1 + baseline_windows) between two windows' changes.
  int baseline_windows = 50;
  double false_alarm_probability = 1e-6;  ///< alpha, per camera and window while it holds
  int min_pylon_marks = 3;  ///< a camera seeing fewer pylon marks in the baseline: not monitored
  std::vector<int> camera_ids;  ///< the cameras monitored; empty: all (an id not in the rig throws)
};

/// One camera's state. motion is the estimated change of its extrinsic since the baseline, a
/// left perturbation of T_c_w (rx, ry, rz, tx, ty, tz; camera frame, rad and m).
struct CameraHealth {
  int camera_id = -1;
  bool baseline_done = false;
  bool monitored = false;  ///< enough pylon marks, positive definite information
  int pylon_marks = 0;     ///< pylon marks seen in the baseline
  bool moved = false;      ///< latched at the first alarm
  std::uint64_t windows_tested = 0;
  std::uint64_t alarms = 0;                ///< windows whose statistic exceeded the threshold
  std::uint64_t first_alarm_exposure = 0;  ///< the monitor's exposure count at the first alarm
  double last_statistic = 0;
  geometry::Vec6 motion = geometry::Vec6::Zero();  ///< at the latest alarm
  geometry::Mat6 motion_cov = geometry::Mat6::Zero();
};

class CalibrationHealthMonitor {
 public:
  /// Throws std::invalid_argument naming the calibration_health field of a bad config.
  CalibrationHealthMonitor(const camera::RigCalibration& rig, const survey::RigidBodySurvey& pylon,
                           const CalibrationHealthConfig& config);

  /// One processed exposure (ExposureProcessor::process): its pylon marks' observations.
  /// Returns true when a camera was newly declared moved (see cameras()). Allocation-free.
  bool update(const AlignedExposure& exposure, const ExposureResult& result);

  /// Noncentrality of a window's statistic when camera `slot` moved by xi (left perturbation of
  /// T_c_w) for a fraction f of the window's exposures: lambda = f^2 xi^T A xi, A the window
  /// change's information with the baseline's mean weight per exposure (0 before the baseline
  /// ends). With noncentral_chi_square_survival it gives the detection probability per window.
  double noncentrality(std::size_t slot, const geometry::Vec6& xi, double fraction) const;

  const std::vector<CameraHealth>& cameras() const { return health_; }
  /// The alarm threshold: chi-square(6) quantile at 1 - false_alarm_probability.
  double threshold() const { return threshold_; }
  std::uint64_t exposures() const { return exposures_; }
  const CalibrationHealthConfig& config() const { return config_; }

 private:
  /// Per camera and pylon mark: the fixed prediction, its Jacobian and the residual sums.
  struct MarkState {
    bool predicted = false;
    geometry::Vec2 pixel = geometry::Vec2::Zero();
    Eigen::Matrix<double, 2, 6> J = Eigen::Matrix<double, 2, 6>::Zero();  ///< d u / d xi
    double w_base = 0, w_window = 0;                                      ///< sums of 1/s^2
    geometry::Vec2 wr_base = geometry::Vec2::Zero(), wr_window = geometry::Vec2::Zero();
  };
  void set_reference(const geometry::Transform& T_w_p);
  void add_observations(const AlignedExposure& exposure, const ExposureResult& result);
  void end_baseline(std::size_t slot);
  bool test_window(std::size_t slot);

  std::vector<camera::CalibratedCamera> cameras_;
  survey::RigidBodySurvey pylon_;
  CalibrationHealthConfig config_;
  double threshold_ = 0;
  bool have_reference_ = false;
  std::uint64_t exposures_ = 0;
  std::vector<CameraHealth> health_;
  std::vector<std::vector<MarkState>> marks_;  ///< [slot][pylon survey index]
  std::vector<int> exposures_in_phase_;        ///< per slot: in the baseline or the window
  std::vector<int> baseline_exposures_;        ///< per slot
  std::vector<bool> seen_;                     ///< per slot: contributed to this exposure
};

/// What the host does with a camera declared moved (`calibration_health.mode`): flag its
/// samples (counted, log, stats); also correct its extrinsic with the estimated motion and its
/// covariance added; or exclude it from the exposures.
enum class CalibrationHealthMode { kFlag, kCorrect, kExclude };

/// The calibration `rig` with camera `camera_id`'s T_c_w moved by `motion` (left perturbation)
/// and `motion_cov` added to its extrinsic covariance (the joint one too, when the rig has it):
/// the old calibration error remains, the motion's estimate adds its own, independent.
camera::RigCalibration corrected_rig(const camera::RigCalibration& rig, int camera_id,
                                     const geometry::Vec6& motion,
                                     const geometry::Mat6& motion_cov);

struct CalibrationHealthCounters {
  std::uint64_t samples_flagged = 0;      ///< samples with status bit calibration_moved
  std::uint64_t corrections = 0;          ///< rigs corrected (correct mode)
  std::uint64_t exposures_excluding = 0;  ///< exposures with a moved camera dropped (exclude)
};

/// The monitor and the mode's policy around ExposureProcessor::process:
///   e = guard.filter(exposure); r = processor.process(e, ...);
///   if (guard.observe(e, r)) processor = ExposureProcessor(guard.rig(), ...);
class CalibrationHealthGuard {
 public:
  CalibrationHealthGuard(const camera::RigCalibration& rig, const survey::RigidBodySurvey& pylon,
                         const CalibrationHealthConfig& config, CalibrationHealthMode mode);

  /// Once a camera is declared moved: a member copy (reused) of `exposure` whose
  /// calibration_moved_mask names the moved cameras that delivered marks, without them in
  /// exclude mode; before that, `exposure` itself.
  const AlignedExposure& filter(const AlignedExposure& exposure);
  /// After processing `exposure` (as filtered): runs the monitor; flagged() tells whether a
  /// camera declared moved contributed. True when the processor must be rebuilt on rig():
  /// correct mode, a full window's motion estimate differing from the correction applied
  /// (chi-square(6) above the monitor's threshold).
  bool observe(const AlignedExposure& exposure, const ExposureResult& result);
  /// The last observed exposure used a camera declared moved (exclude mode: dropped one), as
  /// its status bit calibration_moved says.
  bool flagged() const { return flagged_; }

  const camera::RigCalibration& rig() const { return rig_; }  ///< corrected (correct mode)
  const CalibrationHealthMonitor& monitor() const { return monitor_; }
  const CalibrationHealthCounters& counters() const { return counters_; }
  CalibrationHealthMode mode() const { return mode_; }

 private:
  bool correction_needed(std::size_t slot) const;

  camera::RigCalibration original_, rig_;
  CalibrationHealthMonitor monitor_;
  CalibrationHealthMode mode_;
  CalibrationHealthCounters counters_;
  std::vector<std::uint64_t> alarms_seen_;  ///< per slot: the monitor's alarm count
  std::vector<bool> corrected_;             ///< per slot: a correction applied
  std::vector<geometry::Vec6> applied_;     ///< per slot: the motion applied
  std::vector<geometry::Mat6> applied_cov_;
  AlignedExposure filtered_;
  bool flagged_ = false;
};

}  // namespace storetrack::pipeline
