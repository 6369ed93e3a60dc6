// ExposureProcessor: one aligned exposure -> triangulated marks with covariances, rigid-body
// checks, pylon/store poses with 6x6 covariances, uncertainty budget and the FtiSample
// (docs/uncertainty.md explains the method; TEAM.md "host" is the contract).
//
// Real-time path: first-order propagation (GUM JCGM 100:2008). Errors common to all marks of an
// exposure (intrinsic, extrinsic, camera time offsets) are carried as loadings on shared
// factors, so the pose covariance includes the correlations between marks. monte_carlo() is the
// JCGM 101 check of that propagation on the same exposure.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/match/mark_matcher.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/pipeline/aligned_exposure.hpp"
#include "storetrack/rigid/rigid_check.hpp"
#include "storetrack/survey/survey.hpp"
#include "storetrack/uncertainty/calibration_factors.hpp"
#include "storetrack/uncertainty/sources.hpp"

namespace storetrack::pipeline {

/// Mark identity per observation: ids[e][j] is the mark id of exposure.cameras[e].marks[j],
/// or -1 when unidentified (ignored).
using MarkIds = std::vector<std::vector<int>>;

struct ProcessorConfig {
  std::uint8_t store_id = 0;
  match::MatcherConfig matcher;  ///< used by process(exposure)
  double coverage_factor = 2.0;  ///< k of the expanded uncertainty U = k u
  int min_cameras_per_mark = 2;
  int min_pose_marks = 3;
  /// A body pose is refused (sample not valid, degraded geometry) when the rotation standard
  /// uncertainty its marks' layout allows exceeds this [rad]: nearly collinear marks, where
  /// first-order propagation no longer holds.
  double max_pose_rotation_sigma_rad = 0.02;
  int reference_camera_id = -1;                 ///< -1: the first camera of the RigCalibration
  double rigid_false_alarm_probability = 1e-3;  ///< per body and exposure (intact body)
  double tracking_max_gap_s = 0.05;             ///< older previous positions give no velocity
  /// msg::mark_flags bits whose observations are not used (counted in rejected_by_flags), also
  /// when the ids come from outside the matcher (process(exposure, ids)): the matcher's policy.
  /// A border blob's centroid is pulled inwards by up to a radius, a bias its sigma_px does not
  /// state; with two cameras left it passes the epipolar and rigid-body checks and made the
  /// store attitude's stated uncertainty too small (issue 11, docs/uncertainty.md).
  std::uint8_t rejected_mark_flags = match::MatcherConfig{}.rejected_mark_flags;
  int max_mark_id = 1023;  ///< ids above are counted as bad input
  /// Quantisation step of the wire's pixel coordinates (1/256 px); its variance step^2/12 is
  /// added to each centroid's.
  double pixel_quantisation_px = 1.0 / 256.0;
};

/// One zero matrix per uncertainty source (value-initialising an Eigen matrix leaves it unset).
template <class Matrix>
std::array<Matrix, uncertainty::kNumSources> zero_by_source() {
  std::array<Matrix, uncertainty::kNumSources> by_source;
  for (Matrix& m : by_source)
    m.setZero();
  return by_source;
}

/// A triangulated mark.
struct MarkResult {
  int id = -1;
  char body = '?';  ///< 'p' pylon, 's' store, '?' other
  geometry::Vec3 p_w = geometry::Vec3::Zero();
  geometry::Mat3 cov_w = geometry::Mat3::Zero();  ///< total 3x3 covariance [m^2]
  std::array<geometry::Mat3, uncertainty::kNumSources> cov_by_source =
      zero_by_source<geometry::Mat3>();                ///< survey: zero
  geometry::Vec3 velocity_w = geometry::Vec3::Zero();  ///< from tracking (zero if unknown)
  bool velocity_valid = false;
  bool excluded = false;  ///< removed by the rigid-body test
  struct ObservationResidual {
    int camera_id = -1;
    int mark_index = -1;                                  ///< index in that camera's marks
    geometry::Vec2 residual_px = geometry::Vec2::Zero();  ///< observed - reprojected
    double sigma_px = 0;
  };
  std::vector<ObservationResidual> observations;
  double chi2 = 0;  ///< sum of (residual / sigma)^2 over observations
  /// Loadings on the common calibration factors (3 x factors().num_factors()).
  uncertainty::Loadings3 loadings;
};

/// A pose with its 6x6 covariance over the left perturbation (rx, ry, rz, tx, ty, tz).
struct PoseResult {
  bool valid = false;
  geometry::Transform T = geometry::Transform::Identity();
  geometry::Mat6 cov = geometry::Mat6::Zero();
  std::array<geometry::Mat6, uncertainty::kNumSources> cov_by_source =
      zero_by_source<geometry::Mat6>();
  int marks_used = 0;
  double chi2 = 0;  ///< fit chi-square (block-diagonal weights)
  /// Loadings of the pose perturbation on the common calibration factors (6 x
  /// factors().num_factors(); empty in Monte Carlo draws): cov_by_source of intrinsic,
  /// extrinsic and sync are their column blocks' L L^T. Lets consumers combine poses of
  /// different exposures with their shared calibration errors (PoseTracker).
  uncertainty::Loadings6 loadings;
};

struct ExposureResult {
  msg::FtiSample sample{};
  std::uint32_t trigger_seq = 0;
  time::TaiNs reference_mid_tai_ns = 0;
  int cameras_used = 0;
  std::vector<MarkResult> marks;
  rigid::RigidCheckResult pylon_check, store_check;
  PoseResult T_w_p, T_w_s, T_p_s;
  /// A body pose was fitted to marks seen by single cameras (resection; sample.status
  /// kSingleView): its uncertainty is larger along the cameras' lines of sight.
  bool single_view_pose = false;
  /// (x, y, z, yaw, pitch, roll) of T_p_s and its covariance (what the FtiSample carries).
  Eigen::Matrix<double, 6, 1> xyz_ypr = Eigen::Matrix<double, 6, 1>::Zero();
  geometry::Mat6 cov_xyz_ypr = geometry::Mat6::Zero();
  std::array<geometry::Mat6, uncertainty::kNumSources> cov_xyz_ypr_by_source =
      zero_by_source<geometry::Mat6>();

  /// Set by PoseTracker::update() when T_p_s could not be solved from this exposure and was
  /// predicted from the track instead (sample.status kValid | kExtrapolated). xyz_ypr,
  /// cov_xyz_ypr (including the process noise) and cov_xyz_ypr_by_source then describe the
  /// prediction; T_p_s stays invalid.
  bool extrapolated = false;
  geometry::Transform T_p_s_extrapolated = geometry::Transform::Identity();
  geometry::Mat6 cov_T_p_s_extrapolated = geometry::Mat6::Zero();  ///< left perturbation
  double extrapolation_horizon_s = 0;  ///< time since the last solved T_p_s

  const MarkResult* find_mark(int id) const;
};

/// JCGM 101 Monte Carlo of one exposure: draws centroid noise, calibration parameters and
/// camera time offsets from their stated distributions and repeats the whole solution.
struct MonteCarloResult {
  int draws = 0;  ///< successful draws
  int failed_draws = 0;
  std::vector<int> mark_ids;
  std::vector<geometry::Mat3> mark_cov;          ///< sample covariance per mark (order of mark_ids)
  std::vector<geometry::Vec3> mark_mean_offset;  ///< sample mean - nominal estimate
  geometry::Mat6 cov_T_p_s = geometry::Mat6::Zero();  ///< left-perturbation covariance
  geometry::Mat6 cov_xyz_ypr = geometry::Mat6::Zero();
};

struct ProcessorCounters {
  std::uint64_t exposures = 0;
  std::uint64_t unknown_camera = 0;   ///< camera_id not in the calibration
  std::uint64_t bad_observation = 0;  ///< non-finite pixel or sigma, id out of range
  std::uint64_t rejected_by_flags = 0;
  std::uint64_t ambiguous_ids = 0;    ///< same id twice in one camera: both dropped
  std::uint64_t too_few_cameras = 0;  ///< identified marks seen by < min cameras
  std::uint64_t triangulation_failed = 0;
  std::uint64_t marks_excluded = 0;       ///< by the rigid-body test
  std::uint64_t pose_failed = 0;          ///< exposures without a valid T_p_s
  std::uint64_t degenerate_geometry = 0;  ///< body poses refused: rotation sigma above the max
  std::uint64_t single_view_poses = 0;    ///< body poses from single views (resection)
  /// Single-view resections refused: reprojection chi-square above the rigid-body test's
  /// quantile, not converged or not well determined.
  std::uint64_t single_view_rejected = 0;
};

class ExposureProcessor {
 public:
  ExposureProcessor(const camera::RigCalibration& rig, const survey::RigidBodySurvey& pylon,
                    const survey::RigidBodySurvey& store, const ProcessorConfig& config);

  /// Identifies the marks with the MarkMatcher (host/match: prediction gates, epipolar and
  /// layout checks; set its prior poses through matcher() for acquisition), then processes.
  ExposureResult process(const AlignedExposure& exposure);

  /// Processes an exposure whose marks are already identified (ids per observation, e.g.
  /// simulator truth or an external matcher). Updates the mark tracking (velocities) used for
  /// the synchronisation correction.
  ExposureResult process(const AlignedExposure& exposure, const MarkIds& ids);

  /// JCGM 101 check: `draws` Monte Carlo repetitions of process() for this exposure (with the
  /// current tracking state and the nominal rigid-body exclusions). Does not change the state.
  MonteCarloResult monte_carlo(const AlignedExposure& exposure, const MarkIds& ids, int draws,
                               std::uint64_t seed) const;

  /// Forgets the velocity tracks (and the matcher's tracks).
  void reset_tracking();
  match::MarkMatcher& matcher() { return matcher_; }
  const match::MarkMatcher& matcher() const { return matcher_; }
  const ProcessorCounters& counters() const { return counters_; }
  const uncertainty::CalibrationFactors& factors() const { return factors_; }
  const camera::RigCalibration& rig() const { return rig_; }

 private:
  struct Prepared;
  struct Exclusions;
  Prepared prepare(const AlignedExposure& exposure, const MarkIds& ids,
                   ProcessorCounters& counters) const;
  void solve(const Prepared& prep, const std::vector<camera::CalibratedCamera>& cameras,
             const survey::RigidBodySurvey& pylon_survey,
             const survey::RigidBodySurvey& store_survey, bool with_uncertainty,
             const Exclusions* fixed_exclusions, ExposureResult& out,
             ProcessorCounters& counters) const;
  void fill_sample(const AlignedExposure& exposure, const Prepared& prep,
                   ExposureResult& out) const;

  camera::RigCalibration rig_;
  survey::RigidBodySurvey pylon_, store_;
  ProcessorConfig config_;
  uncertainty::CalibrationFactors factors_;
  std::vector<int> slot_of_camera_id_;  ///< camera_id -> index in rig_.cameras, -1 if unknown

  struct Track {
    bool valid = false;
    time::TaiNs t_ns = 0;
    geometry::Vec3 p_w = geometry::Vec3::Zero();
    geometry::Vec3 velocity_w = geometry::Vec3::Zero();
    bool velocity_valid = false;
  };
  std::vector<Track> tracks_;  ///< indexed by mark id
  /// Last known pose T_w_b per body (0 pylon, 1 store) and its time: starts a resection.
  struct PoseHint {
    std::optional<geometry::Transform> T_w_b;
    time::TaiNs t_ns = 0;
  };
  std::array<PoseHint, 2> pose_hint_;
  match::MarkMatcher matcher_;
  ProcessorCounters counters_;
};

}  // namespace storetrack::pipeline
