// The matcher's internals shared by its stage sources (prediction, gating, verification,
// layouts, tracks): the per-exposure working state and small helpers. Private to host/match.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "storetrack/match/mark_matcher.hpp"
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

/// d p_w / d(left perturbation of T_w_b) for a body point p_b: [-[R p_b]x, I].
inline Eigen::Matrix<double, 3, 6> point_pose_jacobian(const Transform& T_w_b, const Vec3& p_b) {
  Eigen::Matrix<double, 3, 6> G;
  G.leftCols<3>() = -geometry::skew(T_w_b.linear() * p_b);
  G.rightCols<3>() = Mat3::Identity();
  return G;
}

enum class ObsState : std::uint8_t { kUnassigned, kAssigned, kAmbiguous, kUngated };

/// Per-exposure working state.
struct MarkMatcher::Work {
  struct Obs {
    int slot = -1;        ///< index in rig_.cameras
    int cam = -1;         ///< index into Work::cams
    int span_index = -1;  ///< index in the caller's span
    int mark_index = -1;
    Vec2 raw = Vec2::Zero(), xy = Vec2::Zero();
    double sigma = 0;
    Mat2 S_cal = Mat2::Zero();  ///< calibration pixel covariance at the mark (when assigned)
    Mat2 W = Mat2::Identity();  ///< (S_cal + sigma^2 I)^-1 (when assigned)
    int mark = -1;              ///< assigned mark (index in marks_)
    ObsState state = ObsState::kUnassigned;
  };
  struct Cam {
    int slot = -1;
    int span_index = -1;
    std::vector<int> obs;  ///< indices into Work::obs
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
    Mat3 cov = Mat3::Zero();
    double chi2 = 0;
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
  std::vector<Tri> tri;                             ///< per mark
  std::vector<triangulate::Observation> tri_views;  ///< triangulation scratch
  triangulate::Result tri_result;
  std::vector<Vec3> layout_q_b, layout_p_w;  ///< layout fit scratch
  std::vector<double> layout_weights;
  std::vector<bool> fitted;  ///< per body
  std::vector<Transform> T_w_b;
  std::vector<Mat6> cov_b;
  /// Per body: the pose filter extrapolated to this exposure (valid when the body has a track)
  /// and, when its marks updated it, the posterior.
  struct BodyState {
    bool predicted = false;
    BodyTrack pred;
    bool updated = false;
    BodyTrack post;
  };
  std::vector<BodyState> body;
  bool acquired = false;
  MatchCounters counts;
};

}  // namespace storetrack::match
