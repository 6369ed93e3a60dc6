// Mark identification (see mark_matcher.hpp and docs/matching.md for the method): set-up and
// the per-exposure sequence; the stages are in prediction.cpp, gating.cpp, verification.cpp,
// layouts.cpp and tracks.cpp.
//
// Gating follows the standard Mahalanobis / chi-square validation gate of target tracking
// (Bar-Shalom, Li, Kirubarajan, "Estimation with Applications to Tracking and Navigation",
// 2001, sec. 5.4); the multi-view test is the reprojection chi-square of the Gauss-Newton
// triangulation (Hartley & Zisserman, "Multiple View Geometry", 2nd ed., ch. 12), which for two
// views is the epipolar constraint with its uncertainty (estimation/triangulate). The layout fit is
// the absolute orientation of estimation/pose (Umeyama, IEEE TPAMI 13(4), 1991).
#include "matcher_work.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <unordered_map>

#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::match {

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
    : rig_(rig), factors_(rig), bodies_(std::move(bodies)), config_(config) {
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
  regions_.resize(bodies_.size());
  next_search_s_.assign(bodies_.size(), -std::numeric_limits<double>::infinity());
  refused_in_a_row_.assign(bodies_.size(), 0);
  min_mark_spacing_.assign(bodies_.size(), std::numeric_limits<double>::infinity());
  for (size_t i = 0; i < marks_.size(); ++i)
    for (size_t j = i + 1; j < marks_.size(); ++j)
      if (marks_[i].body == marks_[j].body) {
        double& d = min_mark_spacing_[marks_[i].body];
        d = std::min(d, (marks_[i].p_body - marks_[j].p_body).norm());
      }
  compute_calibration_bounds();
  chi2_gate_.assign(kMaxDof + 1, 0.0);
  chi2_competitor_gate_.assign(kMaxDof + 1, 0.0);
  const double miss = 1 - config_.gate_probability;
  for (int dof = 1; dof <= kMaxDof; ++dof) {
    chi2_gate_[dof] = uncertainty::chi_square_quantile(
        uncertainty::Probability(config_.gate_probability), uncertainty::DegreesOfFreedom(dof));
    chi2_competitor_gate_[dof] = uncertainty::chi_square_quantile(
        uncertainty::Probability(1 - miss * miss), uncertainty::DegreesOfFreedom(dof));
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

bool MarkMatcher::set_region(const std::string& body_name, const BodyRegion& region) {
  int body = -1, reference = -1;
  for (int b = 0; b < static_cast<int>(bodies_.size()); ++b) {
    if (bodies_[b].name == body_name) body = b;
    if (bodies_[b].name == region.reference_body) reference = b;
  }
  if (body < 0 || reference < 0 || body == reference) return false;
  regions_[body] = {true, reference, region};
  return true;
}

void MarkMatcher::reset_tracking() {
  for (auto& t : mark_tracks_)
    t.count = 0;
  for (auto& t : body_tracks_)
    t.valid = false;
  next_search_s_.assign(bodies_.size(), -std::numeric_limits<double>::infinity());
  refused_in_a_row_.assign(bodies_.size(), 0);
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
  w.reacquired.assign(bodies_.size(), false);
  w.search_refused.assign(bodies_.size(), false);

  if (t_count > 0) {
    predict(w, t_s);
    gate_and_assign(w);
    verify_views(w);
    verify_layouts(w);
    // A body without a fitted pose (lost: no usable prediction, or its prediction explains
    // none of the observations) is searched for among the free observations.
    reacquire_lost_bodies(w, t_s);
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
  out.cov_b = w.cov_b;
  out.fitted = w.fitted;
  out.reacquired = w.reacquired;

  if (t_count > 0) update_tracks(w, t_s);
  for (size_t b = 0; b < bodies_.size(); ++b) {
    if (w.reacquired[b]) refused_in_a_row_[b] = 0;
    if (!w.search_refused[b]) continue;
    const int doublings = std::min(refused_in_a_row_[b]++, MatcherConfig::kMaxRetryDoublings);
    next_search_s_[b] = t_s + config_.reacquisition_retry_s * static_cast<double>(1 << doublings);
  }

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
  c.lost_body += d.lost_body;
  c.reacquisition_attempted += d.reacquisition_attempted;
  c.reacquisition_accepted += d.reacquisition_accepted;
  c.reacquisition_ambiguous += d.reacquisition_ambiguous;
  c.reacquisition_inconsistent += d.reacquisition_inconsistent;
  c.reacquisition_too_few_marks += d.reacquisition_too_few_marks;
  c.reacquisition_outside_region += d.reacquisition_outside_region;
  c.reacquisition_deferred += d.reacquisition_deferred;
  return out;
}

}  // namespace storetrack::match
