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
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/match/mark_matcher.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/pipeline/aligned_exposure.hpp"
#include "storetrack/pipeline/exposure_result.hpp"
#include "storetrack/pipeline/pose_tracker.hpp"
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
  double rigid_false_alarm_probability = 1e-3;  ///< per body and exposure (intact body)
  /// Every rigid-body pair's sigma and z2 in the result (rigid::RigidCheckConfig); the program
  /// turns it off when nothing reads them (no rigid-body CSV): the same decisions, cheaper.
  bool rigid_pair_statistics = true;
  int max_mark_id = 1023;  ///< given ids above are counted (id_out_of_range) and not used
  /// Extrapolation of T_p_s over short gaps (the processor's PoseTracker).
  PoseTrackerConfig pose_tracker;
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

/// What the processor refused; what the observations' validation and identification refused
/// (bad pixels, flags, ambiguous or duplicate ids) is counted by the matcher
/// (matcher().counters()).
struct ProcessorCounters {
  std::uint64_t exposures = 0;
  std::uint64_t unknown_camera = 0;  ///< camera_id not in the calibration
  /// Observations whose unit did not state its exposure time uncertainty (the calibration's
  /// offset sigma alone stands for them).
  std::uint64_t time_sigma_unknown = 0;
  std::uint64_t id_out_of_range = 0;       ///< given ids above max_mark_id (identify())
  std::uint64_t too_few_cameras = 0;       ///< identified marks seen by < min cameras
  std::uint64_t triangulation_failed = 0;  ///< Monte Carlo draws only (the matcher triangulates)
  std::uint64_t marks_excluded = 0;        ///< by the rigid-body test
  std::uint64_t pose_failed = 0;           ///< exposures without a valid T_p_s
  std::uint64_t degenerate_geometry = 0;   ///< body poses refused: rotation sigma above the max
  std::uint64_t single_view_poses = 0;     ///< body poses from single views (resection)
  /// Single-view resections refused: reprojection chi-square above the rigid-body test's
  /// quantile, not converged or not well determined.
  std::uint64_t single_view_rejected = 0;
};

class ExposureProcessor {
 public:
  ExposureProcessor(const camera::RigCalibration& rig, const survey::RigidBodySurvey& pylon,
                    const survey::RigidBodySurvey& store, const ProcessorConfig& config);

  /// Identifies and triangulates the marks with the MarkMatcher (host/match: prediction gates,
  /// epipolar and layout checks; set its prior poses through matcher() for acquisition), then
  /// processes its result.
  ExposureResult process(const AlignedExposure& exposure);
  /// The same into a caller-owned result, every field overwritten: its marks (observations,
  /// loadings) keep their storage from the previous exposure, so a loop that passes the same
  /// result does not allocate them again for every exposure.
  void process(const AlignedExposure& exposure, ExposureResult& out);

  /// The matcher's estimate of marks already identified (ids per observation, e.g. simulator
  /// truth or an external matcher): MarkMatcher::estimate_identified (updates its tracks).
  match::MatchResult identify(const AlignedExposure& exposure, const MarkIds& ids);

  /// The rest of the chain on the matcher's result for this exposure: its triangulated marks'
  /// uncertainty, rigid-body checks, poses, the sample. Nothing is triangulated again.
  ExposureResult process(const AlignedExposure& exposure, const match::MatchResult& marks);
  void process(const AlignedExposure& exposure, const match::MatchResult& marks,
               ExposureResult& out);

  /// process(exposure, identify(exposure, ids)).
  ExposureResult process(const AlignedExposure& exposure, const MarkIds& ids);

  /// JCGM 101 check: `draws` Monte Carlo repetitions of the estimate behind `marks` (the
  /// matcher's result process() was given for this exposure: same weights, velocities and
  /// rigid-body exclusions; each draw triangulates again). Does not change the state.
  MonteCarloResult monte_carlo(const AlignedExposure& exposure, const match::MatchResult& marks,
                               int draws, std::uint64_t seed) const;

  /// The matcher's bodies, in this order; their motion states (matcher().motion(b)) are the
  /// only ones: the store's holds the solved poses PoseTracker extrapolates from.
  static constexpr int kPylonBody = 0, kStoreBody = 1;

  /// Forgets the motion state (the matcher's tracks and the bodies' BodyMotion).
  void reset_tracking();
  match::MarkMatcher& matcher() { return matcher_; }
  const match::MarkMatcher& matcher() const { return matcher_; }
  const ProcessorCounters& counters() const { return counters_; }
  const uncertainty::CalibrationFactors& factors() const { return factors_; }
  const PoseTracker& pose_tracker() const { return tracker_; }
  const camera::RigCalibration& rig() const { return rig_; }

 private:
  struct Prepared;
  struct Exclusions;
  /// Per-exposure working storage, kept so that an exposure does not allocate it again.
  struct Scratch;
  /// Owns a Scratch; a copy starts empty (scratch only: nothing to copy).
  struct ScratchBuffer {
    ScratchBuffer();
    ScratchBuffer(const ScratchBuffer&);
    ScratchBuffer& operator=(const ScratchBuffer&);
    ScratchBuffer(ScratchBuffer&&) noexcept;
    ScratchBuffer& operator=(ScratchBuffer&&) noexcept;
    ~ScratchBuffer();
    std::unique_ptr<Scratch> scratch;
  };
  /// Fills `prep` for this exposure, reusing its storage.
  void prepare(const AlignedExposure& exposure, const match::MatchResult& marks,
               ProcessorCounters& counters, Prepared& prep) const;
  void solve(const Prepared& prep, const std::vector<camera::CalibratedCamera>& cameras,
             const survey::RigidBodySurvey& pylon_survey,
             const survey::RigidBodySurvey& store_survey, bool with_uncertainty,
             const Exclusions* fixed_exclusions, ExposureResult& out, ProcessorCounters& counters,
             Scratch& scratch) const;
  void fill_sample(const AlignedExposure& exposure, const Prepared& prep,
                   ExposureResult& out) const;
  /// process(exposure, marks) into `out`, whose fields other than marks are as constructed.
  void process_into_new(const AlignedExposure& exposure, const match::MatchResult& marks,
                        ExposureResult& out);

  camera::RigCalibration rig_;
  survey::RigidBodySurvey pylon_, store_;
  ProcessorConfig config_;
  uncertainty::CalibrationFactors factors_;
  std::vector<int> slot_of_camera_id_;  ///< camera_id -> index in rig_.cameras, -1 if unknown

  match::MarkMatcher matcher_;
  match::MatchResult matched_;  ///< the last exposure's matches, their storage reused
  ScratchBuffer scratch_;
  PoseTracker tracker_;
  ProcessorCounters counters_;
};

}  // namespace storetrack::pipeline
