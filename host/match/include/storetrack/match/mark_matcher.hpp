// Mark identification across cameras: which observation of which camera is which mark id.
//
// Usage (host/pipeline, once per aligned exposure):
//
//   match::MarkMatcher matcher(rig, {pylon_survey, store_survey}, match::MatcherConfig{});
//   matcher.set_prior_pose("pylon", T_w_p_nominal, cov_p);   // for (re-)acquisition
//   matcher.set_prior_pose("store", T_w_p_nominal * T_p_s_carriage, cov_s);
//   matcher.set_region("store", {"pylon", T_p_s_carriage, max_angle, box_min, box_max});
//   for each exposure:
//     match::MatchResult m = matcher.match(exposure.cameras);   // span of MarkObservations
//     // m.ids[e][j]: mark id of exposure.cameras[e].marks[j], or -1  (= pipeline::MarkIds)
//     // m.marks: per id, the (camera_id, raw px, undistorted px, sigma_px) observations
//     processor.process(exposure, m.ids);
//
// Method (docs/matching.md): each mark id gets a predicted 3-D position and covariance from
// its own constant-velocity track (previous exposures) or, whichever is tighter, its body's
// constant-velocity pose filter (an EKF over pose, angular rate and velocity, which keeps
// predicting hidden marks and the roll about a collinear row); a body without a track starts
// its filter from its prior pose (acquisition). The prediction is projected into every camera with
// the calibrated model; an observation is assigned to a mark only if each is the other's ONLY
// candidate inside the chi-square gate built from the prediction covariance, the calibration
// covariance and the observation's sigma_px (ambiguities are rejected and counted, never
// resolved by "nearest"). Marks assigned in >= 2 cameras are then triangulated and must pass
// the multi-view epipolar test (reprojection chi-square, dof 2n - 3, with the same sigmas); a
// failing observation is removed only when it is the unique culprit. Finally each body's
// identified marks update its pose filter, whose innovation chi-square is the layout test; a
// fitted body pose
// re-predicts that body's unassigned marks with a tight covariance and the gating is repeated
// (bootstrap from a coarse prior). Tracks are updated from the triangulated positions.
// A body with no usable prediction (track timed out or too uncertain, prior explaining nothing)
// is re-acquired from this exposure's unidentified observations alone: multi-view points
// matched to its survey's distance table, one pose passing the chi-square test, any second
// distinct interpretation refused as ambiguous (src/reacquisition.cpp).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/match/body_motion.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/survey/survey.hpp"
#include "storetrack/time/time.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "storetrack/uncertainty/calibration_factors.hpp"

namespace storetrack::match {

struct MatcherConfig {
  /// Probability that a correct match lies inside a gate (prediction, epipolar and layout
  /// gates are chi-square quantiles at this probability; no fixed pixel gates).
  double gate_probability = 0.9999;
  /// Observations carrying any of these msg::mark_flags bits are never matched.
  /// Merged blobs mix two marks; border blobs are cut by the image edge, so their centroid is
  /// pulled inwards by up to a radius (seen: 3 px at u = 1917.6 of 1920).
  std::uint8_t rejected_mark_flags = msg::mark_flags::kMerged | msg::mark_flags::kBorder;
  /// Used when an observation's sigma_px is not a positive finite number (counted).
  double fallback_sigma_px = 0.2;
  /// Quantisation step of the wire pixel coordinates; step^2/12 is added to each variance.
  double pixel_quantisation_px = 1.0 / 256.0;
  /// Adds the pixel covariance implied by each camera's intrinsic and extrinsic calibration
  /// covariance (first order) to the gates.
  bool use_calibration_covariance = true;
  /// Constant-velocity process noise: standard deviation of the unmodelled acceleration of a
  /// mark [m/s^2] (store ejection peaks near 100 m/s^2, inside the 4-sigma gate).
  double max_acceleration_mps2 = 50.0;
  /// Standard deviation of the velocity of a body or mark with only one past position [m/s]
  /// (bodies start at rest; a store re-acquired in flight needs its prior or layout instead).
  double max_speed_mps = 2.0;
  /// Floor on a predicted position's per-axis standard uncertainty [m] (pod vibration etc.).
  double min_prediction_sigma_m = 3e-4;
  /// Constant-velocity pose track of a body: standard deviation of its unmodelled angular
  /// acceleration [rad/s^2] and of its angular rate when (re-)acquired [rad/s].
  double max_angular_acceleration_radps2 = 100.0;
  double max_angular_speed_radps = 2.0;
  /// Mark tracks older than this give no prediction [s].
  double track_max_gap_s = 0.05;
  /// A body's pose track is extrapolated over gaps up to this long [s] (its covariance grows
  /// with the process noise; ambiguous gates then reject, never guess).
  double body_track_max_gap_s = 0.25;
  /// Bodies with fewer identified, triangulated marks are not fitted (no layout check).
  int min_layout_marks = 3;
  /// A layout fit is used (to verify ids and predict the body's other marks) only when its
  /// marks are not nearly collinear (second / first singular value of the centred survey
  /// coordinates above this) and its pose is well determined (standard uncertainties below).
  double min_layout_spread = 0.1;
  double max_layout_rotation_sigma_rad = 0.01;
  double max_layout_translation_sigma_m = 0.005;
  /// Keep marks identified in only one camera (no epipolar check possible) in the output.
  bool keep_single_view = true;
  /// ... but only when the prediction came from a track or this exposure's layout fit, never
  /// from a prior pose alone.
  bool single_view_requires_track = true;
  /// Predictions further than this outside the image border are not gated [px].
  double image_margin_px = 20.0;
  /// Re-acquisition without a usable prediction (docs/matching.md, step 6): a layout hypothesis
  /// must explain at least this many marks (three points fix a pose and leave only their own
  /// three distances to test, which clutter matches too easily).
  int min_reacquisition_marks = 4;
  /// After a search that found nothing to accept, the body is not searched for again for this
  /// long [s], doubled after each further refusal up to kMaxRetryDoublings times (0.01 s ->
  /// 0.32 s) and back to it once a search is accepted: a search costs 8-40 ms, so while a lost
  /// body stays unfound among free observations (refused as ambiguous: a symmetric layout with
  /// no region) the host would otherwise fall behind the 2.5 ms frame period for good; with the
  /// doubling the search's share falls below 10 % of the thread after 5 refusals
  /// (docs/matching.md). 0: every exposure.
  double reacquisition_retry_s = 0.01;
  static constexpr int kMaxRetryDoublings = 5;
  /// Camera whose calibrated exposure mid-point is the exposure's reference time (the time of
  /// the triangulated points, the tracks and the sample); -1: the rig's first camera. When it
  /// did not deliver, the earliest delivered camera's mid-point.
  int reference_camera_id = -1;
};

/// Where a body can be relative to a reference body (e.g. the store relative to its pylon during
/// the separation). Used only to choose between layout hypotheses of a re-acquisition: a
/// hypothesis outside the region is excluded, so a symmetric layout (the store turned by 180 deg)
/// or a second identical body elsewhere (the store on the other pylon) is told apart instead of
/// refused as ambiguous. Hard bounds, generous by intent (a physical envelope, not a gate).
struct BodyRegion {
  std::string reference_body;  ///< name of the body whose pose frames the region ("pylon")
  /// Nominal pose T_ref_b of the body in the reference body's frame (e.g. the carriage pose).
  geometry::Transform T_ref_b_nominal = geometry::Transform::Identity();
  /// Largest rotation angle between the body's attitude and the nominal one [rad].
  double max_rotation_rad = 0;
  /// Box of the body origin's offset from the nominal origin, reference frame axes [m].
  geometry::Vec3 min_offset_m = geometry::Vec3::Zero();
  geometry::Vec3 max_offset_m = geometry::Vec3::Zero();
};

/// Where a mark's prediction came from.
enum class PredictionSource : std::uint8_t {
  kNone = 0,
  kMarkTrack = 1,  ///< the mark's own constant-velocity track
  kBodyTrack = 2,  ///< extrapolated pose of its body
  kLayout = 3,     ///< pose of its body fitted in this exposure (bootstrap)
  kPrior = 4,      ///< prior pose of its body (acquisition)
};
const char* to_string(PredictionSource source);

/// One observation assigned to a mark.
struct MatchedObservation {
  int camera_id = -1;
  int camera_index = -1;                           ///< index in the span passed to match()
  int mark_index = -1;                             ///< index in that MarkObservations' marks[]
  geometry::Vec2 raw_px = geometry::Vec2::Zero();  ///< as received
  double sigma_px = 0;  ///< per-axis standard uncertainty used (incl. quantisation) [px]
  /// Weight of the view in the triangulation: (sigma_px^2 I + calibration pixel covariance at
  /// the mark)^-1 [px^-2].
  geometry::Mat2 information_px = geometry::Mat2::Identity();
  /// This camera's calibrated exposure mid-point minus the reference time [s].
  double time_offset_s = 0;
};

struct MatchedMark {
  int id = -1;
  int body = -1;  ///< index into the bodies given to the matcher
  PredictionSource source = PredictionSource::kNone;
  std::vector<MatchedObservation> observations;  ///< ascending camera_index
  /// THE position of the mark at the reference time (>= 2 views; estimation/triangulate's
  /// Gauss-Newton weighted by each view's information_px, corrected for the mark's motion
  /// between the reference time and each camera's exposure, with calibration Jacobians and
  /// gains in the order of `observations`): the processor propagates its uncertainty, nothing
  /// triangulates it again. estimate.chi2 is the multi-view test's statistic (dof 2 views - 3),
  /// estimate.cov_weighted the covariance the gates and tracks use.
  bool triangulated = false;
  triangulate::Result estimate;
  /// Velocity of the mark [m/s] from its track (its last two positions), when it has one;
  /// corrects the estimate for the cameras' time offsets. At the second exposure of a track it
  /// is this exposure's position minus the previous one (then used for the time-offset
  /// uncertainty only, not to correct this estimate: motion_corrected false).
  geometry::Vec3 velocity_w = geometry::Vec3::Zero();
  bool velocity_valid = false;
  bool motion_corrected = false;
};

/// Result of one exposure.
struct MatchResult {
  /// Reference time of the exposure (MatcherConfig::reference_camera_id's rule), TAI ns; valid
  /// when has_reference_time (some camera of the rig delivered).
  time::TaiNs reference_mid_tai_ns = 0;
  bool has_reference_time = false;
  std::vector<MatchedMark> marks;  ///< ascending id
  /// ids[e][j]: mark id of cameras[e].marks[j], -1 when not identified (pipeline::MarkIds).
  std::vector<std::vector<int>> ids;
  int observations = 0;  ///< usable observations in this exposure
  int identified = 0;    ///< observations with an id
  int ambiguous = 0;     ///< observations or marks rejected as ambiguous in this exposure
  bool acquired_from_prior = false;  ///< some body was (re-)acquired from its prior pose
  /// Fitted body poses T_w_b (index as bodies), valid when fitted[b], and their 6x6 covariance
  /// (left perturbation, rx ry rz tx ty tz).
  std::vector<geometry::Transform> T_w_b;
  std::vector<geometry::Mat6> cov_b;
  std::vector<bool> fitted;
  /// Per body: found again in this exposure by the re-acquisition search (no prediction used).
  std::vector<bool> reacquired;

  const MatchedMark* find(int id) const;
};

struct MatchCounters {
  std::uint64_t exposures = 0;
  std::uint64_t observations = 0;       ///< usable observations seen
  std::uint64_t identified = 0;         ///< observations given an id
  std::uint64_t unknown_camera = 0;     ///< camera_id not in the rig (whole camera ignored)
  std::uint64_t bad_observation = 0;    ///< non-finite pixel, mark_count out of range
  std::uint64_t fallback_sigma = 0;     ///< sigma_px unusable: fallback_sigma_px used
  std::uint64_t rejected_by_flags = 0;  ///< observation flags in rejected_mark_flags
  /// unproject did not converge for an observation the re-acquisition search needed (tracking
  /// compares projections with raw pixels and undistorts nothing); left out of that search
  std::uint64_t undistort_failed = 0;
  std::uint64_t unmatched = 0;              ///< observation inside no gate
  std::uint64_t ambiguous_observation = 0;  ///< observation inside >= 2 marks' gates
  std::uint64_t ambiguous_mark = 0;         ///< >= 2 observations inside one mark's gate (camera)
  std::uint64_t epipolar_outlier = 0;       ///< observation removed by the multi-view test
  std::uint64_t epipolar_rejected = 0;      ///< mark dropped: views inconsistent, culprit unknown
  std::uint64_t layout_rejected = 0;        ///< mark dropped: inconsistent with its body's survey
  std::uint64_t single_view = 0;            ///< marks identified in exactly one camera
  std::uint64_t acquisitions = 0;           ///< exposures where a body used its prior pose
  std::uint64_t duplicate_camera = 0;       ///< same camera_id twice in one exposure (2nd ignored)
  /// Exposures where a body's extrapolated pose was too uncertain to gate its marks (gate wider
  /// than its smallest mark spacing): the body counts as lost and is searched for instead.
  std::uint64_t lost_body = 0;
  /// Re-acquisition searches (a body without a fitted pose, free observations in >= 2 cameras)
  /// and their outcomes (each search has exactly one).
  std::uint64_t reacquisition_attempted = 0;
  std::uint64_t reacquisition_accepted = 0;
  std::uint64_t reacquisition_ambiguous = 0;       ///< >= 2 distinct hypotheses pass: refused
  std::uint64_t reacquisition_inconsistent = 0;    ///< hypotheses found, none passes the chi-square
  std::uint64_t reacquisition_too_few_marks = 0;   ///< no hypothesis with enough well-spread marks
  std::uint64_t reacquisition_outside_region = 0;  ///< the only passing ones are outside the region
  /// Searches not run: within reacquisition_retry_s of the body's last refused one.
  std::uint64_t reacquisition_deferred = 0;
  /// estimate_identified(): an id given twice in one camera (both observations dropped), ids
  /// of no body (triangulated, no track) and marks whose views could not be triangulated.
  std::uint64_t duplicate_id = 0;
  std::uint64_t given_ids_of_no_body = 0;
  std::uint64_t triangulation_failed = 0;
};

class MarkMatcher {
 public:
  /// `bodies`: surveys of the rigid bodies whose marks are to be identified (pylon, store, ...).
  /// Mark ids must be unique across bodies (std::invalid_argument otherwise).
  MarkMatcher(const camera::RigCalibration& rig, std::vector<survey::RigidBodySurvey> bodies,
              const MatcherConfig& config = {});

  /// Prior pose T_w_b of a body and its 6x6 covariance (left perturbation, rx ry rz tx ty tz)
  /// used whenever the body has no valid track. Returns false if no body has that name.
  bool set_prior_pose(const std::string& body_name, const geometry::Transform& T_w_b,
                      const geometry::Mat6& covariance);
  void clear_prior_pose(const std::string& body_name);

  /// Region the body can occupy relative to another body (used by re-acquisition only).
  /// Returns false if either body is unknown or the region refers to the body itself.
  bool set_region(const std::string& body_name, const BodyRegion& region);

  /// Identifies the marks of one exposure (all cameras that delivered it, any order, missing
  /// cameras simply absent), triangulates them and updates the tracks.
  MatchResult match(std::span<const msg::MarkObservations> cameras);
  /// The same into `out`, whose storage (its marks with their observations and estimates, its
  /// id lists) is reused: the host loop's and the replay's path, which then allocates nothing
  /// per exposure once the exposures' sizes have been seen. Every field is this exposure's.
  void match(std::span<const msg::MarkObservations> cameras, MatchResult& out);

  /// The same for marks already identified elsewhere (ids[e][j]: id of cameras[e].marks[j], -1
  /// none; e.g. the simulator's truth): no gates, no multi-view or layout test, no body fit;
  /// the marks are triangulated exactly as match() does (weights at the tracks' prediction,
  /// else at the linear point; motion correction) and the mark tracks updated. Ids in no
  /// body's survey (scale bars) are triangulated too, body -1, without a track.
  MatchResult estimate_identified(std::span<const msg::MarkObservations> cameras,
                                  const std::vector<std::vector<int>>& ids);

  /// Forgets all tracks and the bodies' motion states (next exposure starts from the priors).
  void reset_tracking();

  /// The motion state of body `body` (index as bodies()): its pose filter, which match()
  /// writes, and its solved poses, which the processor writes.
  BodyMotion& motion(int body) { return motion_.at(static_cast<size_t>(body)); }
  const BodyMotion& motion(int body) const { return motion_.at(static_cast<size_t>(body)); }

  const MatchCounters& counters() const { return counters_; }
  const std::vector<survey::RigidBodySurvey>& bodies() const { return bodies_; }
  const MatcherConfig& config() const { return config_; }

  /// The calibration's covariance of camera `slot`'s pixel of a world point, which the gates
  /// add to the centroid's (zero with use_calibration_covariance off or the point not imaged):
  /// uncertainty::pixel_covariance over the calibration factors the processor states the
  /// marks' uncertainty with, cross terms included.
  geometry::Mat2 calibration_pixel_covariance(int slot, const geometry::Vec3& p_w) const;

 private:
  struct MarkInfo {
    int id;
    int body;
    geometry::Vec3 p_body;
    double survey_sigma_m;
  };
  struct MarkTrack {
    int count = 0;  ///< positions held (0..2)
    double t_s[2] = {0, 0};
    geometry::Vec3 p_w[2];
    geometry::Mat3 cov_w[2];
  };
  struct Prior {
    bool valid = false;
    geometry::Transform T_w_b = geometry::Transform::Identity();
    geometry::Mat6 cov = geometry::Mat6::Zero();
  };
  struct Region {
    bool valid = false;
    int reference = -1;  ///< body index
    BodyRegion region;
  };
  struct Work;

  /// Owns the per-exposure scratch buffers (reused; a copied matcher gets fresh ones).
  struct WorkBuffers {
    WorkBuffers();
    WorkBuffers(const WorkBuffers&);
    WorkBuffers& operator=(const WorkBuffers&);
    WorkBuffers(WorkBuffers&&) noexcept;
    WorkBuffers& operator=(WorkBuffers&&) noexcept;
    ~WorkBuffers();
    std::unique_ptr<Work> work;
  };
  /// trace(calibration pixel covariance) <= a + b / z_cam^2 (per camera slot; pre-gate).
  struct CalibrationBound {
    double a = 0, b = 0;
    /// Smallest singular value of d(pixel)/d(normalised point) over the image [px] (the
    /// re-acquisition's epipolar pre-gate converts pixel sigmas to the normalised plane with it).
    double min_pixel_scale = 0;
  };

  void compute_calibration_bounds();
  double calibration_bound(int slot, double z_cam) const;
  void predict(Work& w, double t_s) const;
  void gate_and_assign(Work& w) const;
  void verify_views(Work& w) const;
  void verify_layouts(Work& w) const;
  bool filter_update(Work& w, int b, const std::vector<int>& members, PoseFilter& post,
                     double& nis) const;
  /// Mark m seen by one camera as a measurement of its body's pose T_w_b: innovation y (pixel
  /// minus projection), Jacobian H = d pixel / d(left perturbation) and information W = R^-1.
  bool single_view_measurement(const Work& w, int m, const geometry::Transform& T_w_b,
                               geometry::Vec2& y, Eigen::Matrix<double, 2, 6>& H,
                               geometry::Mat2& W) const;
  /// Measurement dimension of a filter update: 3 per triangulated mark, 2 per single view.
  static int measurement_dof(const Work& w, const std::vector<int>& members);
  /// THE triangulation of mark m (index in marks_, -1: a mark of no body) from observations
  /// `obs` (Work::obs indices, weights Work::Obs::W), motion-corrected with the mark's
  /// velocity; fills w.tri_result. False when it fails or its chi2 is not finite.
  bool triangulate(Work& w, int m, std::span<const int> obs, const geometry::Vec3& initial) const;
  /// The start of every exposure (match() and estimate_identified()): loads it, resets the
  /// per-exposure state and, when it has a reference time, predicts every mark and takes its
  /// velocity from its track. Returns the exposure's time t_s since the time origin.
  double begin_exposure(Work& w, std::span<const msg::MarkObservations> cameras, MatchResult& out);
  /// Resets `out` to a new result, its storage kept (the marks' in Work's spares).
  static void reuse_result(Work& w, MatchResult& out);
  /// Validates one exposure's observations into the Work (raw pixels); the reference time.
  void load_exposure(Work& w, std::span<const msg::MarkObservations> cameras, MatchResult& out);
  void start_exposure_state(Work& w) const;
  /// Per-mark velocities from the tracks (before triangulation).
  void mark_velocities(Work& w, double t_s) const;
  void finish_exposure(Work& w, double t_s, MatchResult& out);
  /// estimate_identified(): weights at the prediction (else the linear point), then THE
  /// triangulation into w.tri_result; false (counted) when it fails.
  bool triangulate_identified(Work& w, int m, std::span<const int> obs) const;
  void accumulate(const MatchCounters& d);
  void update_tracks(const Work& w, double t_s);
  // Re-acquisition of lost bodies (reacquisition.cpp).
  enum class SearchOutcome : std::uint8_t;
  void reacquire_lost_bodies(Work& w, double t_s) const;
  SearchOutcome search_body(Work& w, int b) const;
  /// Observation o's normalised image point (Work::Obs::xy), undistorted on first use; false
  /// (counted once) when the lens model cannot be inverted there.
  bool undistort(Work& w, int o) const;
  void find_epipolar_pairs(Work& w) const;
  void form_candidates(Work& w) const;
  bool triangulate_free(Work& w, std::span<const int> obs, const geometry::Vec3& initial,
                        bool calibration_at_point, geometry::Vec3& p_w, geometry::Mat3& cov_w,
                        double& chi2) const;
  SearchOutcome choose_hypothesis(const Work& w, int b, int& best) const;
  void accept_reacquisition(Work& w, int b, int hypothesis) const;
  bool inside_region(const Work& w, int b, const geometry::Transform& T_w_b) const;
  void verify_against_reacquired_pose(Work& w, int b) const;

  camera::RigCalibration rig_;
  uncertainty::CalibrationFactors factors_;  ///< of rig_: the gates' pixel covariances
  std::vector<survey::RigidBodySurvey> bodies_;
  MatcherConfig config_;
  std::vector<MarkInfo> marks_;  ///< all marks of all bodies
  std::vector<MarkTrack> mark_tracks_;
  std::vector<BodyMotion> motion_;  ///< per body: its one motion state
  std::vector<Prior> priors_;
  std::vector<Region> regions_;           ///< per body
  std::vector<double> min_mark_spacing_;  ///< per body: smallest distance between two marks [m]
  std::vector<double> next_search_s_;     ///< per body: no re-acquisition search before [s]
  std::vector<int> refused_in_a_row_;     ///< per body: searches refused since the last accepted
  std::vector<double> chi2_gate_;         ///< chi2_gate_[dof] at gate_probability, dof 0..kMaxDof
  /// At 1 - (1 - gate_probability)^2: a re-acquisition hypothesis within it is a competitor
  /// (only dismissed at a false-rejection probability squared), see reacquisition.cpp.
  std::vector<double> chi2_competitor_gate_;
  std::vector<CalibrationBound> cal_bounds_;  ///< per camera slot
  MatchCounters counters_;
  WorkBuffers work_;
  bool have_time_origin_ = false;
  time::TaiNs time_origin_ns_ = 0;
};

/// Pose T_w_b of a body from the world positions of some of its marks (e.g. the installation
/// survey's initial mark positions, for set_prior_pose) by absolute orientation (estimation/pose),
/// and its 6x6 covariance (left perturbation) for positions of standard uncertainty `sigma_m` per
/// axis (plus each mark's survey sigma). Ids not in the survey are ignored. Returns false with
/// fewer than 3 of the body's marks or nearly collinear ones (no defined pose).
bool fit_body_pose(const survey::RigidBodySurvey& body,
                   const std::map<int, geometry::Vec3>& p_w_by_id, double sigma_m,
                   geometry::Transform& T_w_b, geometry::Mat6& covariance);

}  // namespace storetrack::match
