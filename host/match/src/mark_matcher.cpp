// Mark identification (see mark_matcher.hpp and docs/matching.md for the method).
//
// Gating follows the standard Mahalanobis / chi-square validation gate of target tracking
// (Bar-Shalom, Li, Kirubarajan, "Estimation with Applications to Tracking and Navigation",
// 2001, sec. 5.4); the multi-view test is the reprojection chi-square of the Gauss-Newton
// triangulation (Hartley & Zisserman, "Multiple View Geometry", 2nd ed., ch. 12), which for two
// views is the epipolar constraint with its uncertainty (host/triangulate). The layout fit is the
// absolute orientation of host/pose (Umeyama, IEEE TPAMI 13(4), 1991).
#include "storetrack/match/mark_matcher.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <stdexcept>
#include <unordered_map>

#include <Eigen/SVD>

#include "storetrack/pose/body_pose.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::match {

using geometry::Mat2;
using geometry::Mat3;
using geometry::Mat6;
using geometry::Transform;
using geometry::Vec2;
using geometry::Vec3;

namespace {

constexpr int kMaxDof = 2 * 64;

/// d p_w / d(left perturbation of T_w_b) for a body point p_b: [-[R p_b]x, I].
Eigen::Matrix<double, 3, 6> point_pose_jacobian(const Transform& T_w_b, const Vec3& p_b) {
  Eigen::Matrix<double, 3, 6> G;
  G.leftCols<3>() = -geometry::skew(T_w_b.linear() * p_b);
  G.rightCols<3>() = Mat3::Identity();
  return G;
}

/// Body-frame points spread in at least two directions: the second singular value of the centred
/// points is above `min_spread` times the first (else the rotation about their line is free).
bool layout_well_spread(std::span<const Vec3> q_b, double min_spread) {
  Eigen::Matrix3Xd centred(3, static_cast<Eigen::Index>(q_b.size()));
  Vec3 mean = Vec3::Zero();
  for (const Vec3& q : q_b)
    mean += q;
  mean /= static_cast<double>(q_b.size());
  for (size_t i = 0; i < q_b.size(); ++i)
    centred.col(static_cast<Eigen::Index>(i)) = q_b[i] - mean;
  const Vec3 sv = Eigen::JacobiSVD<Eigen::Matrix3Xd>(centred).singularValues();
  return sv[1] > min_spread * sv[0];
}

enum class ObsState : std::uint8_t { kUnassigned, kAssigned, kAmbiguous, kUngated };

}  // namespace

bool fit_body_pose(const survey::RigidBodySurvey& body, const std::map<int, Vec3>& p_w_by_id,
                   double sigma_m, Transform& T_w_b, Mat6& covariance) {
  std::vector<const survey::SurveyedMark*> used;
  std::vector<Vec3> p_w;
  for (const auto& m : body.marks)
    if (const auto it = p_w_by_id.find(m.id); it != p_w_by_id.end()) {
      used.push_back(&m);
      p_w.push_back(it->second);
    }
  const int n = static_cast<int>(used.size());
  if (n < 3) return false;
  std::vector<Vec3> q_b(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i)
    q_b[static_cast<size_t>(i)] = used[i]->p_body;
  if (!layout_well_spread(q_b, 0.1)) return false;  // collinear: rotation about the line undefined
  const std::vector<double> equal_weights(static_cast<size_t>(n), 1.0);
  if (!pose::absolute_orientation(q_b, p_w, equal_weights, T_w_b)) return false;
  Mat6 info = Mat6::Zero();
  for (int i = 0; i < n; ++i) {
    const double var = sigma_m * sigma_m + used[i]->sigma_m * used[i]->sigma_m;
    const auto G = point_pose_jacobian(T_w_b, used[i]->p_body);
    info += G.transpose() * G / var;
  }
  return uncertainty::inverse_spd<6>(info, covariance);
}

const char* to_string(PredictionSource source) {
  switch (source) {
    case PredictionSource::kNone:
      return "none";
    case PredictionSource::kMarkTrack:
      return "mark_track";
    case PredictionSource::kBodyTrack:
      return "body_track";
    case PredictionSource::kLayout:
      return "layout";
    case PredictionSource::kPrior:
      return "prior";
  }
  return "?";
}

const MatchedMark* MatchResult::find(int id) const {
  const auto it = std::lower_bound(marks.begin(), marks.end(), id,
                                   [](const MatchedMark& m, int v) { return m.id < v; });
  return it != marks.end() && it->id == id ? &*it : nullptr;
}

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

MarkMatcher::WorkBuffers::WorkBuffers() : work(std::make_unique<Work>()) {}
MarkMatcher::WorkBuffers::WorkBuffers(const WorkBuffers&) : work(std::make_unique<Work>()) {}
MarkMatcher::WorkBuffers& MarkMatcher::WorkBuffers::operator=(const WorkBuffers&) {
  return *this;  // scratch only: nothing to copy
}
MarkMatcher::WorkBuffers::WorkBuffers(WorkBuffers&&) noexcept = default;
MarkMatcher::WorkBuffers& MarkMatcher::WorkBuffers::operator=(WorkBuffers&&) noexcept = default;
MarkMatcher::WorkBuffers::~WorkBuffers() = default;

MarkMatcher::MarkMatcher(const camera::RigCalibration& rig,
                         std::vector<survey::RigidBodySurvey> bodies, const MatcherConfig& config)
    : rig_(rig), bodies_(std::move(bodies)), config_(config) {
  if (!(config_.gate_probability > 0 && config_.gate_probability < 1))
    throw std::invalid_argument("MatcherConfig.gate_probability must be in (0, 1)");
  std::unordered_map<int, int> seen;
  for (int b = 0; b < static_cast<int>(bodies_.size()); ++b)
    for (const auto& m : bodies_[b].marks) {
      if (!seen.emplace(m.id, b).second)
        throw std::invalid_argument("MarkMatcher: mark id " + std::to_string(m.id) +
                                    " appears twice in the surveys");
      marks_.push_back({m.id, b, m.p_body, m.sigma_m});
    }
  std::sort(marks_.begin(), marks_.end(),
            [](const MarkInfo& a, const MarkInfo& b) { return a.id < b.id; });
  mark_tracks_.resize(marks_.size());
  body_tracks_.resize(bodies_.size());
  priors_.resize(bodies_.size());
  compute_calibration_bounds();
  chi2_gate_.assign(kMaxDof + 1, 0.0);
  for (int dof = 1; dof <= kMaxDof; ++dof)
    chi2_gate_[dof] = uncertainty::chi_square_quantile(
        uncertainty::Probability(config_.gate_probability), uncertainty::DegreesOfFreedom(dof));
}

void MarkMatcher::compute_calibration_bounds() {
  // Upper bound on trace(S_cal) (pixel covariance from the calibration covariance) over the
  // image (plus margin) as a + b / z^2 for a point at depth z: with p_cam = z (x, y, 1) the
  // intrinsic and rotation parts do not depend on z, the translation part scales with 1/z, and
  // (u + v)^T C (u + v) <= 2 u^T C u + 2 v^T C v. Evaluated on a grid, x 1.5 between nodes.
  cal_bounds_.assign(rig_.cameras.size(), {});
  if (!config_.use_calibration_covariance) return;
  for (size_t slot = 0; slot < rig_.cameras.size(); ++slot) {
    const auto& cal = rig_.cameras[slot];
    const auto& in = cal.model.intrinsics();
    const double margin = config_.image_margin_px + 0.5;
    constexpr int kGrid = 12;
    double a = 0, b = 0;
    for (int iu = 0; iu <= kGrid; ++iu)
      for (int iv = 0; iv <= kGrid; ++iv) {
        const Vec2 px(-margin + (in.width + 2 * margin) * iu / kGrid,
                      -margin + (in.height + 2 * margin) * iv / kGrid);
        const auto xy = cal.model.unproject(px, 1e-6, 50);
        if (!xy) continue;
        const Vec3 p_cam(xy->x(), xy->y(), 1.0);
        Eigen::Matrix<double, 2, 3> J_cam;
        Eigen::Matrix<double, 2, camera::kNumIntrinsics> J_int;
        if (!cal.model.project(p_cam, &J_cam, &J_int)) continue;
        const Eigen::Matrix<double, 2, 3> J_rot = -J_cam * geometry::skew(p_cam);
        const Mat3 C_rot = cal.extrinsic_covariance.topLeftCorner<3, 3>();
        const Mat3 C_trans = cal.extrinsic_covariance.bottomRightCorner<3, 3>();
        const double t_int = (J_int * cal.intrinsic_covariance * J_int.transpose()).trace();
        const double t_rot = (J_rot * C_rot * J_rot.transpose()).trace();
        const double t_trans = (J_cam * C_trans * J_cam.transpose()).trace();
        a = std::max(a, t_int + 2 * t_rot);
        b = std::max(b, 2 * t_trans);
      }
    // intrinsic and extrinsic parts add: trace(A + B) = trace A + trace B
    cal_bounds_[slot] = {1.5 * a, 1.5 * b};
  }
}

bool MarkMatcher::set_prior_pose(const std::string& body_name, const Transform& T_w_b,
                                 const Mat6& covariance) {
  for (size_t b = 0; b < bodies_.size(); ++b)
    if (bodies_[b].name == body_name) {
      priors_[b] = {true, T_w_b, covariance};
      return true;
    }
  return false;
}

void MarkMatcher::clear_prior_pose(const std::string& body_name) {
  for (size_t b = 0; b < bodies_.size(); ++b)
    if (bodies_[b].name == body_name) priors_[b].valid = false;
}

void MarkMatcher::reset_tracking() {
  for (auto& t : mark_tracks_)
    t.count = 0;
  for (auto& t : body_tracks_)
    t.valid = false;
}

void MarkMatcher::predict(Work& w, double t_s) const {
  const double floor2 = config_.min_prediction_sigma_m * config_.min_prediction_sigma_m;
  // Body poses first: the constant-velocity pose filter extrapolated to t_s (Bar-Shalom et
  // al. 2001, sec. 6.3.3, discrete white-noise acceleration, per axis for translation and
  // rotation), else the prior pose (acquisition).
  std::vector<Transform> body_T(bodies_.size());
  std::vector<Mat6> body_cov(bodies_.size());
  std::vector<PredictionSource> body_src(bodies_.size(), PredictionSource::kNone);
  w.body.assign(bodies_.size(), {});
  for (size_t b = 0; b < bodies_.size(); ++b) {
    const BodyTrack& bt = body_tracks_[b];
    const double dt = t_s - bt.t_s;
    if (bt.valid && dt >= 0 && dt <= config_.body_track_max_gap_s) {
      BodyTrack p = bt;
      p.t_s = t_s;
      p.T_w_b.linear() = geometry::rotation_from_rotvec(bt.omega_w * dt) * bt.T_w_b.linear();
      p.T_w_b.translation() = bt.T_w_b.translation() + bt.v_w * dt;
      // F = [I dt*I; 0 I] over (pose, rates): F P F^T by 6x6 blocks.
      const Mat6 Ppp = bt.P.topLeftCorner<6, 6>(), Ppr = bt.P.topRightCorner<6, 6>(),
                 Prr = bt.P.bottomRightCorner<6, 6>();
      p.P.topLeftCorner<6, 6>() = Ppp + dt * (Ppr + Ppr.transpose()) + dt * dt * Prr;
      p.P.topRightCorner<6, 6>() = Ppr + dt * Prr;
      p.P.bottomLeftCorner<6, 6>() = p.P.topRightCorner<6, 6>().transpose();
      Mat12 Q = Mat12::Zero();
      const double qa =
          config_.max_angular_acceleration_radps2 * config_.max_angular_acceleration_radps2;
      const double ql = config_.max_acceleration_mps2 * config_.max_acceleration_mps2;
      const double d2 = dt * dt, d3 = d2 * dt, d4 = d3 * dt;
      for (int i = 0; i < 3; ++i) {
        Q(i, i) = qa * d4 / 4;
        Q(i, 6 + i) = Q(6 + i, i) = qa * d3 / 2;
        Q(6 + i, 6 + i) = qa * d2;
        Q(3 + i, 3 + i) = ql * d4 / 4;
        Q(3 + i, 9 + i) = Q(9 + i, 3 + i) = ql * d3 / 2;
        Q(9 + i, 9 + i) = ql * d2;
      }
      p.P += Q;
      w.body[b].predicted = true;
      w.body[b].pred = p;
      body_T[b] = p.T_w_b;
      body_cov[b] = p.P.topLeftCorner<6, 6>();
      body_src[b] = PredictionSource::kBodyTrack;
    } else if (priors_[b].valid) {
      // Acquisition: the prior pose is the filter's prediction (at rest, rates with their
      // a-priori spread), so even one or two marks, or a collinear row, start the track; the
      // innovation test then checks the marks against the prior and the survey together.
      BodyTrack p;
      p.valid = true;
      p.t_s = t_s;
      p.T_w_b = priors_[b].T_w_b;
      p.P.topLeftCorner<6, 6>() = priors_[b].cov;
      const double wr = config_.max_angular_speed_radps, vr = config_.max_speed_mps;
      p.P.block<3, 3>(6, 6) = wr * wr * Mat3::Identity();
      p.P.block<3, 3>(9, 9) = vr * vr * Mat3::Identity();
      w.body[b].predicted = true;
      w.body[b].pred = p;
      body_T[b] = priors_[b].T_w_b;
      body_cov[b] = priors_[b].cov;
      body_src[b] = PredictionSource::kPrior;
    }
  }

  w.pred.assign(marks_.size(), {});
  for (size_t m = 0; m < marks_.size(); ++m) {
    const MarkInfo& info = marks_[m];
    const MarkTrack& mt = mark_tracks_[m];
    const int last = mt.count - 1;
    const int b = info.body;
    // Candidates: the mark's own track and its body's pose. The one with the smaller
    // covariance wins: a fresh mark track beats a body extrapolation, but a mark that has been
    // hidden for a while (its track covariance grows with the gap) is predicted from its body,
    // so its gate does not swallow its neighbours' observations.
    Work::Pred from_track, from_body;
    if (mt.count > 0 && t_s - mt.t_s[last] <= config_.track_max_gap_s) {
      const double dt = t_s - mt.t_s[last];
      const double accel = 0.5 * config_.max_acceleration_mps2 * dt * dt;
      if (mt.count == 2 && mt.t_s[1] > mt.t_s[0]) {
        const double r = dt / (mt.t_s[1] - mt.t_s[0]);
        from_track.p = mt.p_w[1] + r * (mt.p_w[1] - mt.p_w[0]);
        from_track.cov = (1 + r) * (1 + r) * mt.cov_w[1] + r * r * mt.cov_w[0] +
                         (accel * accel + floor2) * Mat3::Identity();
      } else {
        const double v = config_.max_speed_mps * dt;
        from_track.p = mt.p_w[last];
        from_track.cov = mt.cov_w[last] + (v * v + accel * accel + floor2) * Mat3::Identity();
      }
      from_track.source = PredictionSource::kMarkTrack;
      from_track.valid = true;
    }
    if (body_src[b] != PredictionSource::kNone) {
      const auto G = point_pose_jacobian(body_T[b], info.p_body);
      from_body.p = body_T[b] * info.p_body;
      from_body.cov = G * body_cov[b] * G.transpose() +
                      (info.survey_sigma_m * info.survey_sigma_m + floor2) * Mat3::Identity();
      from_body.source = body_src[b];
      from_body.valid = true;
    }
    auto& pr = w.pred[m];
    if (from_track.valid && (!from_body.valid || from_track.cov.trace() <= from_body.cov.trace()))
      pr = from_track;
    else
      pr = from_body;
    if (pr.valid && pr.source == PredictionSource::kPrior) w.acquired = true;
  }
}

void MarkMatcher::gate_and_assign(Work& w) const {
  const double gate = chi2_gate_[2];
  for (int c = 0; c < static_cast<int>(w.cams.size()); ++c) {
    const Work::Cam& cam = w.cams[c];
    const camera::CalibratedCamera& cal = rig_.cameras[cam.slot];
    const camera::Intrinsics& in = cal.model.intrinsics();
    const Mat3 R_c_w = cal.T_c_w.linear();
    const Vec3 t_c_w = cal.T_c_w.translation();
    // This camera's free observations and their largest variance (for the pixel pre-gate).
    auto& free_obs = w.free_obs;
    free_obs.clear();
    double max_var = 0;
    for (int o : cam.obs)
      if (w.obs[o].state != ObsState::kAssigned) {
        free_obs.push_back(o);
        max_var = std::max(max_var, w.obs[o].sigma * w.obs[o].sigma);
      }
    // Candidate marks: predicted and not yet assigned in this camera. The second (layout) pass
    // re-gates every remaining mark, so an observation a tight layout prediction claims is
    // still ambiguous when a coarse prediction of another mark also covers it.
    auto& cand = w.cand;
    cand.clear();
    for (int m = 0; m < static_cast<int>(marks_.size()); ++m) {
      const auto& pr = w.pred[m];
      if (!pr.valid) continue;
      bool already = false;
      for (int o : w.assigned[m])
        already = already || w.obs[o].cam == c;
      if (already) continue;
      const Vec3 p_cam = R_c_w * pr.p + t_c_w;
      Eigen::Matrix<double, 2, 3> J_cam;
      const auto px = cal.model.project(p_cam, &J_cam);
      if (!px) continue;
      const double margin = config_.image_margin_px;
      if (px->x() < -0.5 - margin || px->x() > in.width - 0.5 + margin || px->y() < -0.5 - margin ||
          px->y() > in.height - 0.5 + margin)
        continue;
      const Eigen::Matrix<double, 2, 3> J_w = J_cam * R_c_w;
      Work::Cand cd;
      cd.mark = m;
      cd.px = *px;
      cd.p_w = pr.p;
      cd.z = p_cam.z();
      cd.S_pred = J_w * pr.cov * J_w.transpose();
      // Pre-gate radius: lambda_max(S) <= trace(S_pred) + bound on trace(S_cal) + max sigma^2,
      // and d^T S^-1 d >= |d|^2 / lambda_max(S); pairs further apart cannot be in the gate.
      cd.radius2 = gate * (cd.S_pred.trace() + calibration_bound(cam.slot, p_cam.z()) + max_var);
      cand.push_back(cd);
    }
    const int M = static_cast<int>(cand.size()), N = static_cast<int>(free_obs.size());
    auto& mark_hits = w.mark_hits;
    auto& mark_hit = w.mark_hit;
    auto& obs_hits = w.obs_hits;
    auto& obs_hit = w.obs_hit;
    mark_hits.assign(M, 0);
    mark_hit.assign(M, -1);
    obs_hits.assign(N, 0);
    obs_hit.assign(N, -1);
    for (int i = 0; i < M; ++i) {
      Work::Cand& cd = cand[i];
      for (int k = 0; k < N; ++k) {
        const auto& ob = w.obs[free_obs[k]];
        const Vec2 d = ob.raw - cd.px;
        if (d.squaredNorm() > cd.radius2) continue;
        if (!cd.cal_done) {
          // The calibration part varies slowly over the image and with depth: reuse this mark's
          // value from a previous exposure while its projection stayed within kCacheRadiusPx
          // and its depth within 5 % (cache per mark and camera, invalidated otherwise).
          constexpr double kCacheRadiusPx = 16.0;
          auto& cache = w.cal_cache[static_cast<size_t>(cd.mark) * rig_.cameras.size() +
                                    static_cast<size_t>(cam.slot)];
          if (!(cache.valid && (cache.px - cd.px).squaredNorm() < kCacheRadiusPx * kCacheRadiusPx &&
                std::abs(cd.z / cache.z - 1) < 0.05)) {
            cache.S_cal = calibration_pixel_covariance(cam.slot, cd.p_w);
            cache.px = cd.px;
            cache.z = cd.z;
            cache.valid = true;
          }
          cd.S_cal = cache.S_cal;
          cd.cal_done = true;
        }
        const Mat2 S = cd.S_pred + cd.S_cal + ob.sigma * ob.sigma * Mat2::Identity();
        const double det = S(0, 0) * S(1, 1) - S(0, 1) * S(1, 0);
        if (!(det > 0)) continue;
        const double d2 = (S(1, 1) * d.x() * d.x() - (S(0, 1) + S(1, 0)) * d.x() * d.y() +
                           S(0, 0) * d.y() * d.y()) /
                          det;
        if (!(d2 <= gate)) continue;
        ++mark_hits[i];
        mark_hit[i] = k;
        ++obs_hits[k];
        obs_hit[k] = i;
      }
    }
    for (int k = 0; k < N; ++k) {
      auto& ob = w.obs[free_obs[k]];
      if (obs_hits[k] == 0) {
        ob.state = ObsState::kUngated;
        continue;
      }
      const int i = obs_hit[k];
      if (obs_hits[k] == 1 && mark_hits[i] == 1) {
        // S_cal is positive semidefinite and sigma > 0: the sum is positive definite unless the
        // calibration covariance is corrupt; such an observation is left ungated.
        if (!uncertainty::inverse_spd<2>(
                Mat2(cand[i].S_cal + ob.sigma * ob.sigma * Mat2::Identity()), ob.W)) {
          ob.state = ObsState::kUngated;
          continue;
        }
        ob.state = ObsState::kAssigned;
        ob.mark = cand[i].mark;
        ob.S_cal = cand[i].S_cal;
        w.assigned[cand[i].mark].push_back(free_obs[k]);
        w.dirty[cand[i].mark] = true;
      } else {
        ob.state = ObsState::kAmbiguous;
      }
    }
    for (int i = 0; i < M; ++i) {
      const std::uint64_t bit = std::uint64_t{1} << c;
      auto& amb = w.ambiguous_cams[cand[i].mark];
      amb = mark_hits[i] >= 2 ? (amb | bit) : (amb & ~bit);
    }
  }
}

Mat2 MarkMatcher::calibration_pixel_covariance(int slot, const Vec3& p_w) const {
  if (!config_.use_calibration_covariance) return Mat2::Zero();
  const camera::CalibratedCamera& cal = rig_.cameras[slot];
  camera::ProjectionJacobians J;
  if (!cal.model.project_world(cal.T_c_w, p_w, &J)) return Mat2::Zero();
  // Coefficient-based (lazy) products: Eigen would send the 2x13x13 product to its blocked
  // GEMM kernel, which costs more than the arithmetic here.
  const Eigen::Matrix<double, 2, camera::kNumIntrinsics> JC =
      J.d_intrinsics.lazyProduct(cal.intrinsic_covariance);
  const Eigen::Matrix<double, 2, 6> JE = J.d_pose.lazyProduct(cal.extrinsic_covariance);
  return JC.lazyProduct(J.d_intrinsics.transpose()) + JE.lazyProduct(J.d_pose.transpose());
}

double MarkMatcher::calibration_bound(int slot, double z_cam) const {
  const auto& bd = cal_bounds_[slot];
  return bd.a + bd.b / (z_cam * z_cam);
}

bool MarkMatcher::triangulate(Work& w, const std::vector<int>& obs, const Vec3& initial, Vec3& p_w,
                              Mat3& cov_w, double& chi2) const {
  if (obs.size() < 2) return false;
  // host/triangulate's Gauss-Newton on the raw-pixel reprojection error, started at the mark's
  // prediction (inside its gate, i.e. close), weighted by each observation's full information
  // (sigma^2 I + calibration part, the latter evaluated at the prediction during gating: it
  // varies negligibly over the gate). Its chi2 is the multi-view consistency statistic.
  auto& views = w.tri_views;
  views.clear();
  for (int o : obs) {
    const auto& ob = w.obs[o];
    const auto& cal = rig_.cameras[ob.slot];
    triangulate::Observation v;
    v.model = &cal.model;
    v.T_c_w = cal.T_c_w;
    v.pixel_px = ob.raw;
    v.sigma_px = ob.sigma;
    v.information_px = ob.W;
    views.push_back(v);
  }
  triangulate::Options options;
  options.initial_p_w = initial;
  options.calibration_jacobians = false;  // the matcher needs the point and its covariance only
  options.max_iterations = 6;
  options.step_tolerance_m = 1e-6;  // 1 um: far below any mark's uncertainty
  if (!triangulate::triangulate(views, options, w.tri_result)) return false;
  p_w = w.tri_result.p_w;
  cov_w = w.tri_result.cov_centroid;
  chi2 = w.tri_result.chi2;
  return std::isfinite(chi2);
}

void MarkMatcher::verify_views(Work& w) const {
  for (int m = 0; m < static_cast<int>(marks_.size()); ++m) {
    // Only marks whose assignments changed since they were last verified.
    if (!w.dirty[m]) continue;
    w.dirty[m] = false;
    auto& as = w.assigned[m];
    auto& tri = w.tri[m];
    tri = {};
    if (as.size() < 2) continue;
    Vec3 p;
    Mat3 cov;
    double chi2 = 0;
    const int n = static_cast<int>(as.size());
    const Vec3 initial = w.pred[m].p;
    const bool ok = triangulate(w, as, initial, p, cov, chi2);
    if (ok && chi2 <= chi2_gate_[2 * n - 3]) {
      tri = {true, p, cov, chi2};
      continue;
    }
    // Inconsistent views. With >= 3 views, drop the one observation whose removal makes the
    // rest consistent, if exactly one does; otherwise the mark is not identified at all.
    int culprit = -1, passing = 0;
    Work::Tri best;
    if (n >= 3) {
      for (int k = 0; k < n; ++k) {
        std::vector<int> rest = as;
        rest.erase(rest.begin() + k);
        double c2 = 0;
        if (triangulate(w, rest, initial, p, cov, c2) && c2 <= chi2_gate_[2 * (n - 1) - 3]) {
          ++passing;
          culprit = k;
          best = {true, p, cov, c2};
        }
      }
    }
    if (passing == 1) {
      auto& ob = w.obs[as[culprit]];
      ob.state = ObsState::kUngated;
      ob.mark = -1;
      as.erase(as.begin() + culprit);
      tri = best;
      ++w.counts.epipolar_outlier;
    } else {
      for (int o : as) {
        w.obs[o].state = ObsState::kUngated;
        w.obs[o].mark = -1;
      }
      as.clear();
      ++w.counts.epipolar_rejected;
    }
  }
}

bool MarkMatcher::filter_update(const Work& w, int b, const std::vector<int>& members,
                                BodyTrack& post, double& nis) const {
  // Extended Kalman filter update (Bar-Shalom et al. 2001, sec. 5.2 and 10.3). The marks
  // measure the pose only, so the pose is updated in information form on its 6x6 block,
  // Info = Ppp^-1 + sum G^T W G, with one relinearisation (iterated EKF, sec. 10.3.2), and the
  // rates follow through their correlation with the pose (L = Prp Ppp^-1, exact for a
  // measurement of a sub-state). The normalised innovation squared
  // y^T (G Ppp G^T + R)^-1 y = y^T W y - g^T Info^-1 g (matrix inversion lemma) at the prediction.
  const BodyTrack& pred = w.body[b].pred;
  const Mat6 Ppp = pred.P.topLeftCorner<6, 6>();
  Mat6 Ppp_inv;
  if (!uncertainty::inverse_spd<6>(Ppp, Ppp_inv)) return false;
  geometry::Vec6 delta = geometry::Vec6::Zero();
  Mat6 info, Ppp_post;
  for (int iter = 0; iter < 2; ++iter) {
    const Transform T = geometry::perturb_left(pred.T_w_b, delta);
    info = Ppp_inv;
    geometry::Vec6 g = -Ppp_inv * delta;
    double yWy = 0;
    for (int m : members) {
      const double s = marks_[m].survey_sigma_m;
      Mat3 W;
      if (!uncertainty::inverse_spd<3>(Mat3(w.tri[m].cov + s * s * Mat3::Identity()), W))
        return false;
      const Vec3 y = w.tri[m].p - T * marks_[m].p_body;
      const auto G = point_pose_jacobian(T, marks_[m].p_body);
      const Eigen::Matrix<double, 6, 3> GtW = G.transpose() * W;
      info.noalias() += GtW * G;
      g.noalias() += GtW * y;
      yWy += y.dot(W * y);
    }
    if (!uncertainty::inverse_spd<6>(info, Ppp_post)) return false;
    const geometry::Vec6 step = Ppp_post * g;
    if (!step.allFinite()) return false;
    if (iter == 0) nis = yWy - g.dot(step);
    delta += step;
  }
  const Mat6 L = pred.P.bottomLeftCorner<6, 6>() * Ppp_inv;  // rates | pose gain
  post = pred;
  post.T_w_b = geometry::perturb_left(pred.T_w_b, delta);
  const geometry::Vec6 d_rates = L * delta;
  post.omega_w += d_rates.head<3>();
  post.v_w += d_rates.tail<3>();
  post.P.topLeftCorner<6, 6>() = 0.5 * (Ppp_post + Ppp_post.transpose());
  post.P.bottomLeftCorner<6, 6>() = L * post.P.topLeftCorner<6, 6>();
  post.P.topRightCorner<6, 6>() = post.P.bottomLeftCorner<6, 6>().transpose();
  const Mat6 Prr = pred.P.bottomRightCorner<6, 6>() - L * pred.P.topRightCorner<6, 6>() +
                   L * post.P.topLeftCorner<6, 6>() * L.transpose();
  post.P.bottomRightCorner<6, 6>() = 0.5 * (Prr + Prr.transpose());
  return post.P.allFinite() && std::isfinite(nis);
}

void MarkMatcher::verify_layouts(Work& w) const {
  // Marks whose ids their body's layout does not confirm lose their observations (left for the
  // next gating pass) and leave the body's member list.
  // The layout test failed: when leaving out exactly one member makes it pass (only tried with
  // at least min_members), that member's id is rejected; otherwise the wrong id cannot be told
  // and none of this body's ids is trusted.
  const auto reject_unique_culprit = [&w](std::vector<int>& members, size_t min_members,
                                          const auto& passes_without) {
    int culprit = -1, passing = 0;
    if (members.size() >= min_members) {
      for (size_t k = 0; k < members.size(); ++k) {
        std::vector<int> rest = members;
        rest.erase(rest.begin() + static_cast<long>(k));
        if (passes_without(rest)) {
          ++passing;
          culprit = static_cast<int>(k);
        }
      }
    }
    const std::vector<int> drop =
        passing == 1 ? std::vector<int>{members[static_cast<size_t>(culprit)]} : members;
    for (int m : drop) {
      for (int o : w.assigned[m]) {
        w.obs[o].state = ObsState::kUngated;
        w.obs[o].mark = -1;
      }
      w.assigned[m].clear();
      w.tri[m] = {};
      ++w.counts.layout_rejected;
      members.erase(std::find(members.begin(), members.end(), m));
    }
  };
  for (int b = 0; b < static_cast<int>(bodies_.size()); ++b) {
    w.fitted[b] = false;
    w.body[b].updated = false;
    std::vector<int> members;
    for (int m = 0; m < static_cast<int>(marks_.size()); ++m)
      if (marks_[m].body == b && w.tri[m].valid) members.push_back(m);
    if (w.body[b].predicted) {
      // Tracked body: Kalman update of its pose filter with the triangulated marks; the
      // normalised innovation squared (dof 3n) is the layout test. Works with any number of
      // marks, collinear ones included (the filter carries the unobserved roll).
      while (!members.empty()) {
        BodyTrack post;
        double nis = 0;
        if (filter_update(w, b, members, post, nis) &&
            nis <= chi2_gate_[std::min(kMaxDof, 3 * static_cast<int>(members.size()))]) {
          w.body[b].updated = true;
          w.body[b].post = post;
          w.fitted[b] = true;
          w.T_w_b[b] = post.T_w_b;
          w.cov_b[b] = post.P.topLeftCorner<6, 6>();
          break;
        }
        reject_unique_culprit(members, 2, [&](const std::vector<int>& rest) {
          BodyTrack post_rest;
          double nis_rest = 0;
          return filter_update(w, b, rest, post_rest, nis_rest) &&
                 nis_rest <= chi2_gate_[std::min(kMaxDof, 3 * static_cast<int>(rest.size()))];
        });
      }
      continue;
    }
    // Fit and test; on failure remove the unique culprit (>= 4 marks) and try again.
    while (static_cast<int>(members.size()) >= std::max(3, config_.min_layout_marks)) {
      // Fit (false: no pose or no covariance, i.e. nothing to test) and chi-square test.
      auto fit = [&](const std::vector<int>& set, Transform& T, Mat6& cov, bool& consistent) {
        const int n = static_cast<int>(set.size());
        std::vector<Vec3> q_b(set.size()), p_w(set.size());
        for (int i = 0; i < n; ++i) {
          q_b[i] = marks_[set[i]].p_body;
          p_w[i] = w.tri[set[i]].p;
        }
        const std::vector<double> equal_weights(set.size(), 1.0);
        if (!pose::absolute_orientation(q_b, p_w, equal_weights, T)) return false;
        Mat6 info = Mat6::Zero();
        double chi2 = 0;
        for (int i = 0; i < n; ++i) {
          const double s = marks_[set[i]].survey_sigma_m;
          Mat3 W;
          if (!uncertainty::inverse_spd<3>(Mat3(w.tri[set[i]].cov + s * s * Mat3::Identity()), W))
            return false;
          const Vec3 e = w.tri[set[i]].p - T * marks_[set[i]].p_body;
          chi2 += e.dot(W * e);
          const auto G = point_pose_jacobian(T, marks_[set[i]].p_body);
          info += G.transpose() * W * G;
        }
        if (!uncertainty::inverse_spd<6>(info, cov)) return false;
        consistent = chi2 <= chi2_gate_[3 * n - 6];
        return true;
      };
      // A layout whose marks are (nearly) collinear leaves the rotation about that line
      // undetermined: Umeyama then returns an arbitrary roll that passes the chi-square test.
      // Such a fit neither verifies ids nor predicts the other marks.
      auto well_posed = [&](const std::vector<int>& set, const Mat6& cov) {
        std::vector<Vec3> q_b(set.size());
        for (size_t i = 0; i < set.size(); ++i)
          q_b[i] = marks_[set[i]].p_body;
        if (!layout_well_spread(q_b, config_.min_layout_spread)) return false;
        const double rot_var = cov.topLeftCorner<3, 3>().diagonal().maxCoeff();
        const double trans_var = cov.bottomRightCorner<3, 3>().diagonal().maxCoeff();
        return cov.allFinite() && std::sqrt(rot_var) <= config_.max_layout_rotation_sigma_rad &&
               std::sqrt(trans_var) <= config_.max_layout_translation_sigma_m;
      };
      Transform T;
      Mat6 cov;
      bool consistent = false;
      // Cannot check: ids rest on their predictions.
      if (!fit(members, T, cov, consistent) || !well_posed(members, cov)) break;
      if (consistent) {
        w.fitted[b] = true;
        w.T_w_b[b] = T;
        w.cov_b[b] = cov;
        break;
      }
      reject_unique_culprit(members, 4, [&](const std::vector<int>& rest) {
        Transform T2;
        Mat6 cov2;
        bool consistent2 = false;
        return fit(rest, T2, cov2, consistent2) && consistent2 && well_posed(rest, cov2);
      });
    }
    // Unverifiable single-view or untriangulated assignments of an unfitted body stay as they
    // are (their ids rest on the prediction alone, see MatcherConfig::single_view_*).
  }
}

void MarkMatcher::update_tracks(const Work& w, double t_s) {
  for (size_t m = 0; m < marks_.size(); ++m) {
    if (!w.tri[m].valid) continue;
    MarkTrack& mt = mark_tracks_[m];
    if (mt.count > 0 && t_s - mt.t_s[mt.count - 1] > config_.track_max_gap_s) mt.count = 0;
    if (mt.count == 2) {
      mt.t_s[0] = mt.t_s[1];
      mt.p_w[0] = mt.p_w[1];
      mt.cov_w[0] = mt.cov_w[1];
      mt.count = 1;
    }
    mt.t_s[mt.count] = t_s;
    mt.p_w[mt.count] = w.tri[m].p;
    mt.cov_w[mt.count] = w.tri[m].cov;
    ++mt.count;
  }
  for (size_t b = 0; b < bodies_.size(); ++b) {
    BodyTrack& bt = body_tracks_[b];
    if (w.body[b].updated) {
      bt = w.body[b].post;
      bt.valid = true;
      continue;
    }
    if (!w.fitted[b]) continue;
    // (Re-)acquired by a layout fit: a new filter with the fit's pose covariance, at rest with
    // the a-priori spread of the rates (MatcherConfig::max_speed_mps, max_angular_speed_radps).
    BodyTrack fresh;
    fresh.valid = true;
    fresh.t_s = t_s;
    fresh.T_w_b = w.T_w_b[b];
    fresh.P.topLeftCorner<6, 6>() = w.cov_b[b];
    const double wr = config_.max_angular_speed_radps, vr = config_.max_speed_mps;
    fresh.P.block<3, 3>(6, 6) = wr * wr * Mat3::Identity();
    fresh.P.block<3, 3>(9, 9) = vr * vr * Mat3::Identity();
    bt = fresh;
  }
}

MatchResult MarkMatcher::match(std::span<const msg::MarkObservations> cameras) {
  Work& w = *work_.work;  // buffers reused across exposures (no per-call reallocation)
  w.obs.clear();
  w.cams.clear();
  w.acquired = false;
  w.counts = {};
  MatchResult out;
  out.ids.resize(cameras.size());
  ++w.counts.exposures;

  // Observations: validate, undistort; exposure time = mean calibrated mid-point.
  double t_sum_ns = 0;
  int t_count = 0;
  time::TaiNs t_ref = 0;
  for (int e = 0; e < static_cast<int>(cameras.size()); ++e) {
    const msg::MarkObservations& mo = cameras[e];
    const int count = std::min<int>(mo.mark_count, static_cast<int>(mo.marks.size()));
    out.ids[e].assign(count, -1);
    if (mo.mark_count > mo.marks.size()) ++w.counts.bad_observation;
    int slot = -1;
    for (int s = 0; s < static_cast<int>(rig_.cameras.size()); ++s)
      if (rig_.cameras[s].camera_id == mo.camera_id) slot = s;
    if (slot < 0) {
      ++w.counts.unknown_camera;
      continue;
    }
    bool duplicate = false;
    for (const auto& c : w.cams)
      duplicate = duplicate || c.slot == slot;
    if (duplicate) {
      ++w.counts.duplicate_camera;
      continue;
    }
    const auto& cal = rig_.cameras[slot];
    const double mid_ns = static_cast<double>(mo.exposure_duration_ns) / 2 + cal.exposure_offset_ns;
    if (t_count == 0) t_ref = mo.exposure_start_tai_ns;
    t_sum_ns += static_cast<double>(mo.exposure_start_tai_ns - t_ref) + mid_ns;
    ++t_count;
    Work::Cam cam;
    cam.slot = slot;
    cam.span_index = e;
    const double q2 = config_.pixel_quantisation_px * config_.pixel_quantisation_px / 12;
    for (int j = 0; j < count; ++j) {
      const msg::MarkObservation& mk = mo.marks[j];
      if (!std::isfinite(mk.x_px) || !std::isfinite(mk.y_px)) {
        ++w.counts.bad_observation;
        continue;
      }
      if (mk.flags & config_.rejected_mark_flags) {
        ++w.counts.rejected_by_flags;
        continue;
      }
      double sigma = mk.sigma_px;
      if (!std::isfinite(sigma) || !(sigma > 0)) {
        sigma = config_.fallback_sigma_px;
        ++w.counts.fallback_sigma;
      }
      Work::Obs ob;
      ob.slot = slot;
      ob.cam = static_cast<int>(w.cams.size());
      ob.span_index = e;
      ob.mark_index = j;
      ob.raw = Vec2(mk.x_px, mk.y_px);
      // 1e-4 px: 40x below the wire quantisation step (1/256 px), fewer iterations than 1e-6.
      const auto xy = cal.model.unproject(ob.raw, 1e-4, 30);
      if (!xy) {
        ++w.counts.undistort_failed;
        continue;
      }
      ob.xy = *xy;
      ob.sigma = std::sqrt(sigma * sigma + q2);
      cam.obs.push_back(static_cast<int>(w.obs.size()));
      w.obs.push_back(ob);
      ++w.counts.observations;
    }
    w.cams.push_back(std::move(cam));
  }
  out.observations = static_cast<int>(w.obs.size());
  if (t_count > 0)
    out.t_mid_tai_ns = t_ref + static_cast<time::TaiNs>(std::llround(t_sum_ns / t_count));
  if (!have_time_origin_ && t_count > 0) {
    have_time_origin_ = true;
    time_origin_ns_ = out.t_mid_tai_ns;
  }
  const double t_s = static_cast<double>(out.t_mid_tai_ns - time_origin_ns_) * 1e-9;

  w.assigned.resize(marks_.size());
  for (auto& as : w.assigned)
    as.clear();
  w.ambiguous_cams.assign(marks_.size(), 0);
  w.cal_cache.resize(marks_.size() * rig_.cameras.size());
  w.dirty.assign(marks_.size(), false);
  w.tri.assign(marks_.size(), {});
  w.fitted.assign(bodies_.size(), false);
  w.T_w_b.assign(bodies_.size(), Transform::Identity());
  w.cov_b.assign(bodies_.size(), Mat6::Zero());
  w.body.assign(bodies_.size(), {});

  if (t_count > 0) {
    predict(w, t_s);
    gate_and_assign(w);
    verify_views(w);
    verify_layouts(w);
    // Bootstrap: a fitted body re-predicts its still-unassigned marks from this exposure's
    // layout fit (tight), which resolves what the coarse prediction left ambiguous.
    // Needed only when some observation is still without an id.
    bool free_left = false;
    for (const auto& ob : w.obs)
      free_left = free_left || ob.state != ObsState::kAssigned;
    bool any = false;
    for (size_t b = 0; b < bodies_.size() && free_left; ++b) {
      if (!w.fitted[b]) continue;
      for (size_t m = 0; m < marks_.size(); ++m) {
        if (marks_[m].body != static_cast<int>(b) || w.assigned[m].size() == w.cams.size())
          continue;
        const auto G = point_pose_jacobian(w.T_w_b[b], marks_[m].p_body);
        const double s2 = marks_[m].survey_sigma_m * marks_[m].survey_sigma_m +
                          config_.min_prediction_sigma_m * config_.min_prediction_sigma_m;
        w.pred[m].p = w.T_w_b[b] * marks_[m].p_body;
        w.pred[m].cov = G * w.cov_b[b] * G.transpose() + s2 * Mat3::Identity();
        w.pred[m].source = PredictionSource::kLayout;
        w.pred[m].valid = true;
        any = true;
      }
    }
    if (any) {
      gate_and_assign(w);
      verify_views(w);
      verify_layouts(w);
    }
  }

  // Single views: no multi-view check is possible; keep only if allowed.
  for (size_t m = 0; m < marks_.size(); ++m) {
    auto& as = w.assigned[m];
    if (as.size() != 1) continue;
    const bool from_track = w.pred[m].source != PredictionSource::kPrior;
    if (!config_.keep_single_view || (config_.single_view_requires_track && !from_track)) {
      w.obs[as[0]].state = ObsState::kUngated;
      w.obs[as[0]].mark = -1;
      as.clear();
    } else {
      ++w.counts.single_view;
    }
  }

  // Result.
  for (size_t m = 0; m < marks_.size(); ++m) {
    const auto& as = w.assigned[m];
    if (as.empty()) continue;
    MatchedMark mm;
    mm.id = marks_[m].id;
    mm.body = marks_[m].body;
    mm.source = w.pred[m].source;
    for (int o : as) {
      const auto& ob = w.obs[o];
      const auto& cal = rig_.cameras[ob.slot];
      mm.observations.push_back({cal.camera_id, ob.span_index, ob.mark_index, ob.raw,
                                 cal.model.ideal_pixel(ob.xy), ob.xy, ob.sigma});
      out.ids[ob.span_index][ob.mark_index] = mm.id;
    }
    std::sort(mm.observations.begin(), mm.observations.end(),
              [](const MatchedObservation& a, const MatchedObservation& b) {
                return a.camera_index < b.camera_index;
              });
    mm.triangulated = w.tri[m].valid;
    mm.p_w = w.tri[m].p;
    mm.cov_w = w.tri[m].cov;
    mm.epipolar_chi2 = w.tri[m].chi2;
    out.marks.push_back(std::move(mm));
    out.identified += static_cast<int>(as.size());
  }
  w.counts.identified += static_cast<std::uint64_t>(out.identified);
  for (const auto& ob : w.obs) {
    if (ob.state == ObsState::kAmbiguous) {
      ++w.counts.ambiguous_observation;
      ++out.ambiguous;
    } else if (ob.state == ObsState::kUngated) {
      ++w.counts.unmatched;
    }
  }
  for (size_t m = 0; m < marks_.size(); ++m) {
    // Per camera where the mark's gate held >= 2 observations (it may be identified in others).
    const int n_amb = std::popcount(w.ambiguous_cams[m]);
    w.counts.ambiguous_mark += static_cast<std::uint64_t>(n_amb);
    out.ambiguous += n_amb;
  }
  out.acquired_from_prior = w.acquired;
  if (w.acquired) ++w.counts.acquisitions;
  out.T_w_b = w.T_w_b;
  out.fitted = w.fitted;

  if (t_count > 0) update_tracks(w, t_s);

  // Accumulate counters.
  auto& c = counters_;
  const auto& d = w.counts;
  c.exposures += d.exposures;
  c.observations += d.observations;
  c.identified += d.identified;
  c.unknown_camera += d.unknown_camera;
  c.bad_observation += d.bad_observation;
  c.fallback_sigma += d.fallback_sigma;
  c.rejected_by_flags += d.rejected_by_flags;
  c.undistort_failed += d.undistort_failed;
  c.unmatched += d.unmatched;
  c.ambiguous_observation += d.ambiguous_observation;
  c.ambiguous_mark += d.ambiguous_mark;
  c.epipolar_outlier += d.epipolar_outlier;
  c.epipolar_rejected += d.epipolar_rejected;
  c.layout_rejected += d.layout_rejected;
  c.single_view += d.single_view;
  c.acquisitions += d.acquisitions;
  c.duplicate_camera += d.duplicate_camera;
  return out;
}

}  // namespace storetrack::match
