// The matcher's internals shared by its stage sources (prediction, gating, verification,
// layouts, tracks): the per-exposure working state and small helpers. Private to host/match.
#pragma once

#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "storetrack/match/mark_estimator.hpp"
#include "storetrack/match/mark_matcher.hpp"
#include "storetrack/pose/body_pose.hpp"
#include "storetrack/triangulate/triangulate.hpp"

namespace storetrack::match {

using geometry::Mat2;
using geometry::Mat3;
using geometry::Mat6;
using geometry::Transform;
using geometry::Vec2;
using geometry::Vec3;

/// Largest chi-square dof with a precomputed gate (MarkMatcher::chi2_gate_).
constexpr int kMaxDof = 2 * 64;

/// Absolute orientation (estimation/pose) of surveyed points q_b onto measured world points p_w,
/// each with its total 3x3 covariance cov_w (measurement + survey): the pose, its covariance (G^T W
/// G)^-1 and the chi-square sum of e^T W e (dof 3n - 6). src/layouts.cpp.
struct LayoutFit {
  Transform T_w_b = Transform::Identity();
  Mat6 cov = Mat6::Zero();
  double chi2 = 0;
};
bool fit_layout(pose::PointsInBody q_b, pose::PointsInWorld p_w, std::span<const Mat3> cov_w,
                std::vector<double>& weights_scratch, LayoutFit& out);
/// Body-frame points spread in at least two directions (second / first singular value of the
/// centred points above min_spread; else the rotation about their line is free).
bool layout_well_spread(std::span<const Vec3> q_b, double min_spread);
/// A fit that can verify ids and predict the body's other marks: well-spread marks and a pose
/// known to MatcherConfig::max_layout_rotation_sigma_rad / max_layout_translation_sigma_m.
bool layout_well_posed(std::span<const Vec3> q_b, const Mat6& cov, const MatcherConfig& config);

/// Re-acquisition (reacquisition.cpp): two free observations of different cameras that pass
/// the epipolar test, and their two-view point.
struct EpipolarPair {
  int o1 = -1, o2 = -1;
  Vec3 p = Vec3::Zero();
};
/// A 3-D point triangulated from free observations of >= 2 cameras.
struct CandidatePoint {
  std::vector<int> obs;  ///< observation indices, ascending, one per camera
  Vec3 p = Vec3::Zero();
  Mat3 cov = Mat3::Zero();  ///< triangulation covariance
  double chi2 = 0;          ///< reprojection chi-square, dof 2 views - 3
  int views = 0;
};
/// Survey marks assigned to candidate points, and the fitted pose.
struct LayoutHypothesis {
  std::vector<std::pair<int, int>> pairs;  ///< (mark index in MarkMatcher::marks_, candidate)
  LayoutFit fit;
  bool well_posed = false;
  bool consistent = false;  ///< chi-square within the gate (may be accepted)
  bool plausible = false;   ///< within the competitor gate (counts against another's acceptance)
  /// Observations of the explained candidates seen in >= 3 views, ascending (a two-view point
  /// may be a false correspondence, so it does not make one explanation larger than another).
  std::vector<int> obs;
  /// The same before the trim (trim): what the pose explains; a superset of obs.
  std::vector<int> explained;
};

enum class ObsState : std::uint8_t { kUnassigned, kAssigned, kAmbiguous, kUngated };
enum class Undistortion : std::uint8_t { kNotYet, kDone, kFailed };

/// Per-exposure working state.
struct MarkMatcher::Work {
  struct Obs {
    int slot = -1;        ///< index in rig_.cameras
    int cam = -1;         ///< index into Work::cams
    int span_index = -1;  ///< index in the caller's span
    int mark_index = -1;
    Vec2 raw = Vec2::Zero();
    /// Normalised image point, valid when undistortion is kDone: only the re-acquisition
    /// search's rays need it (MarkMatcher::undistort).
    Vec2 xy = Vec2::Zero();
    Undistortion undistortion = Undistortion::kNotYet;
    double sigma = 0;
    Mat2 S_cal = Mat2::Zero();  ///< calibration pixel covariance at the mark (when assigned)
    Mat2 W = Mat2::Identity();  ///< (S_cal + sigma^2 I)^-1 (when assigned)
    int mark = -1;              ///< assigned mark (index in marks_)
    ObsState state = ObsState::kUnassigned;
    /// The gate's projection of mark start_mark's prediction start_p_w into this camera: the
    /// first pass of that mark's triangulation from that prediction (MarkMatcher::triangulate).
    triangulate::StartProjection start;
    int start_mark = -1;
    Vec3 start_p_w = Vec3::Zero();
  };
  struct Cam {
    int slot = -1;
    int span_index = -1;
    time::TaiNs mid_tai_ns = 0;  ///< calibrated exposure mid-point
    double dt_s = 0;             ///< mid-point minus the exposure's reference time
    std::vector<int> obs;        ///< indices into Work::obs
  };
  struct Pred {
    bool valid = false;
    Vec3 p = Vec3::Zero();
    Mat3 cov = Mat3::Zero();
    PredictionSource source = PredictionSource::kNone;
  };
  struct Tri {
    bool valid = false;
    Vec3 p = Vec3::Zero();
    Mat3 cov = Mat3::Zero();  ///< estimate.cov_weighted (gates, layouts, tracks)
    double chi2 = 0;
    /// THE estimate (MatchedMark::estimate); handed to the result by finish_exposure.
    triangulate::Result estimate;
    /// A triangulation that passed (or needed no) test: the mark's point and estimate. The
    /// estimate is swapped with `scratch` (the triangulation's result, written anew by the
    /// next one): neither copies nor allocates.
    void accept(triangulate::Result& scratch) {
      valid = true;
      p = scratch.p_w;
      cov = scratch.cov_weighted;
      chi2 = scratch.chi2;
      std::swap(estimate, scratch);
    }
    /// No estimate (the storage of the last one is kept for the next accept()).
    void reject() {
      valid = false;
      p.setZero();
      cov.setZero();
      chi2 = 0;
    }
  };
  /// Per mark: velocity from its track's last two positions (corrects the cameras' time offsets).
  struct Motion {
    bool valid = false;
    Vec3 v_w = Vec3::Zero();
  };
  /// estimate_identified(): a given id in no body's survey (e.g. a scale bar's mark).
  struct OtherMark {
    int id = -1;
    std::vector<int> obs;
    Tri tri;
  };
  std::vector<Obs> obs;
  std::vector<Cam> cams;
  std::vector<Pred> pred;                     ///< per mark
  std::vector<std::vector<int>> assigned;     ///< per mark: observation indices
  std::vector<std::uint64_t> ambiguous_cams;  ///< per mark: bit c = ambiguous in cams[c]
  std::vector<bool> dirty;                    ///< per mark: assignments changed since last verified
  /// Gating scratch (one camera at a time).
  struct Cand {
    int mark = -1;
    Vec2 px = Vec2::Zero();
    Eigen::Matrix<double, 2, 3> J_w = Eigen::Matrix<double, 2, 3>::Zero();  ///< d px / d p_w
    Vec3 p_w = Vec3::Zero();
    Mat2 S_pred = Mat2::Zero();
    Mat2 S_cal = Mat2::Zero();
    bool cal_done = false;
    double radius2 = 0;
    double z = 0;  ///< depth in the camera [m]
  };
  /// Calibration pixel covariance per (mark, camera slot), reused across exposures.
  struct CalCache {
    bool valid = false;
    Vec2 px = Vec2::Zero();
    double z = 0;
    Mat2 S_cal = Mat2::Zero();
  };
  std::vector<CalCache> cal_cache;
  std::vector<Cand> cand;
  std::vector<int> free_obs, mark_hits, mark_hit, obs_hits, obs_hit;
  /// gate_and_assign: a camera's free observations as (column, index in free_obs), by column.
  std::vector<std::pair<double, int>> free_by_x;
  std::vector<Tri> tri;        ///< per mark
  std::vector<Motion> motion;  ///< per mark
  std::vector<OtherMark> others;
  /// Marks of the previous result, their storage reused by the next (MarkMatcher::reuse_result).
  std::vector<MatchedMark> spare_marks;
  /// The observation lists of the previous exposure's cameras (load_exposure reuses them).
  std::vector<std::vector<int>> spare_cam_obs;
  std::vector<triangulate::Observation> tri_views;  ///< triangulation scratch
  triangulate::Result tri_result;
  std::vector<Vec3> layout_q_b, layout_p_w;  ///< layout fit scratch
  std::vector<Mat3> layout_cov;
  std::vector<double> layout_weights;
  std::vector<int> layout_members;         ///< verify_layouts: one body's marks
  std::vector<Mat3> filter_point_weights;  ///< filter_update: the triangulated marks' weights
  std::vector<bool> fitted;                ///< per body
  std::vector<Transform> T_w_b;
  std::vector<Mat6> cov_b;
  /// Per body: the pose filter extrapolated to this exposure (valid when the body has a track)
  /// and, when its marks updated it, the posterior.
  struct BodyState {
    bool predicted = false;
    /// The prediction is the body's own filter (not its prior): marks it identifies in a single
    /// camera may update it (docs/matching.md, step 5).
    bool from_track = false;
    PoseFilter pred;
    bool updated = false;
    PoseFilter post;
  };
  std::vector<BodyState> body;
  /// Re-acquisition scratch (reacquisition.cpp).
  std::vector<std::vector<int>> free_by_cam;
  std::vector<EpipolarPair> epipolar_pairs;
  std::vector<std::vector<int>> compatible;  ///< per observation: epipolar partners, ascending
  std::vector<CandidatePoint> candidates;
  std::vector<LayoutHypothesis> hypotheses;
  std::vector<bool> lost;            ///< per body: its extrapolated pose was too uncertain to gate
  std::vector<bool> reacquired;      ///< per body: found by the re-acquisition search
  std::vector<bool> search_refused;  ///< per body: searched for and not accepted
  std::vector<Pred> pred_track, pred_body;  ///< prediction scratch, per mark
  bool acquired = false;
  MatchCounters counts;

  /// Takes mark m's id back from its observations (they become `to`) and forgets its point.
  void unassign_mark(int m, ObsState to) {
    for (int o : assigned[m]) {
      obs[o].state = to;
      obs[o].mark = -1;
    }
    assigned[m].clear();
    tri[m].reject();
  }
};

}  // namespace storetrack::match
