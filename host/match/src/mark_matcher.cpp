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

#include "storetrack/uncertainty/spd_inverse.hpp"
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
  motion_.resize(bodies_.size());
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
  if (config_.reference_camera_id >= 0 &&
      std::none_of(rig_.cameras.begin(), rig_.cameras.end(),
                   [&](const auto& c) { return c.camera_id == config_.reference_camera_id; }))
    throw std::invalid_argument("MatcherConfig.reference_camera_id " +
                                std::to_string(config_.reference_camera_id) + " is not in the rig");
  if (rig_.cameras.empty()) throw std::invalid_argument("MarkMatcher: empty rig");
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
  for (BodyMotion& m : motion_)
    m.reset();
  next_search_s_.assign(bodies_.size(), -std::numeric_limits<double>::infinity());
  refused_in_a_row_.assign(bodies_.size(), 0);
}

void MarkMatcher::load_exposure(Work& w, std::span<const msg::MarkObservations> cameras,
                                MatchResult& out) {
  w.obs.clear();
  for (Work::Cam& c : w.cams)
    w.spare_cam_obs.push_back(std::move(c.obs));
  w.cams.clear();
  w.others.clear();
  w.acquired = false;
  w.counts = {};
  out.ids.resize(cameras.size());
  ++w.counts.exposures;
  const int ref_id = config_.reference_camera_id >= 0 ? config_.reference_camera_id
                                                      : rig_.cameras.front().camera_id;
  bool ref_delivered = false;
  const double q2 = config_.pixel_quantisation_px * config_.pixel_quantisation_px / 12;
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
    Work::Cam cam;
    if (!w.spare_cam_obs.empty()) {
      cam.obs = std::move(w.spare_cam_obs.back());
      cam.obs.clear();
      w.spare_cam_obs.pop_back();
    }
    cam.slot = slot;
    cam.span_index = e;
    // Integer ns: TAI ns since 1970 do not fit a double's mantissa at ns resolution.
    cam.mid_tai_ns = mo.exposure_start_tai_ns +
                     static_cast<time::TaiNs>(mo.exposure_duration_ns / 2) +
                     static_cast<time::TaiNs>(std::llround(cal.exposure_offset_ns));
    if (mo.camera_id == ref_id) {
      out.reference_mid_tai_ns = cam.mid_tai_ns;
      ref_delivered = true;
    } else if (!ref_delivered &&
               (!out.has_reference_time || cam.mid_tai_ns < out.reference_mid_tai_ns)) {
      out.reference_mid_tai_ns = cam.mid_tai_ns;
    }
    out.has_reference_time = true;
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
      ob.sigma = std::sqrt(sigma * sigma + q2);
      cam.obs.push_back(static_cast<int>(w.obs.size()));
      w.obs.push_back(ob);
      ++w.counts.observations;
    }
    w.cams.push_back(std::move(cam));
  }
  for (Work::Cam& cam : w.cams)
    cam.dt_s = static_cast<double>(cam.mid_tai_ns - out.reference_mid_tai_ns) * 1e-9;
  out.observations = static_cast<int>(w.obs.size());
  if (!have_time_origin_ && out.has_reference_time) {
    have_time_origin_ = true;
    time_origin_ns_ = out.reference_mid_tai_ns;
  }
}

void MarkMatcher::start_exposure_state(Work& w) const {
  w.assigned.resize(marks_.size());
  for (auto& as : w.assigned)
    as.clear();
  w.ambiguous_cams.assign(marks_.size(), 0);
  w.cal_cache.resize(marks_.size() * rig_.cameras.size());
  w.dirty.assign(marks_.size(), false);
  w.tri.resize(marks_.size());
  for (Work::Tri& tri : w.tri)
    tri.reject();  // its estimate keeps its storage: read only when valid
  w.motion.assign(marks_.size(), {});
  w.fitted.assign(bodies_.size(), false);
  w.T_w_b.assign(bodies_.size(), Transform::Identity());
  w.cov_b.assign(bodies_.size(), Mat6::Zero());
  w.body.assign(bodies_.size(), {});
  w.reacquired.assign(bodies_.size(), false);
  w.search_refused.assign(bodies_.size(), false);
}

void MarkMatcher::mark_velocities(Work& w, double t_s) const {
  for (size_t m = 0; m < marks_.size(); ++m) {
    const MarkTrack& mt = mark_tracks_[m];
    if (mt.count == 2 && mt.t_s[1] > mt.t_s[0] && t_s - mt.t_s[1] <= config_.track_max_gap_s) {
      w.motion[m].valid = true;
      w.motion[m].v_w = (mt.p_w[1] - mt.p_w[0]) / (mt.t_s[1] - mt.t_s[0]);
    }
  }
}

void MarkMatcher::reuse_result(Work& w, MatchResult& out) {
  for (MatchedMark& mm : out.marks)
    w.spare_marks.push_back(std::move(mm));
  MatchResult next;
  next.marks = std::move(out.marks);
  next.marks.clear();
  next.ids = std::move(out.ids);  // load_exposure assigns every list
  next.T_w_b = std::move(out.T_w_b);
  next.cov_b = std::move(out.cov_b);
  next.fitted = std::move(out.fitted);
  next.reacquired = std::move(out.reacquired);
  out = std::move(next);
}

double MarkMatcher::begin_exposure(Work& w, std::span<const msg::MarkObservations> cameras,
                                   MatchResult& out) {
  reuse_result(w, out);
  load_exposure(w, cameras, out);
  start_exposure_state(w);
  const double t_s = static_cast<double>(out.reference_mid_tai_ns - time_origin_ns_) * 1e-9;
  if (out.has_reference_time) {
    predict(w, t_s);
    mark_velocities(w, t_s);
  }
  return t_s;
}

MatchResult MarkMatcher::match(std::span<const msg::MarkObservations> cameras) {
  MatchResult out;
  match(cameras, out);
  return out;
}

void MarkMatcher::match(std::span<const msg::MarkObservations> cameras, MatchResult& out) {
  Work& w = *work_.work;  // buffers reused across exposures (no per-call reallocation)
  const double t_s = begin_exposure(w, cameras, out);

  if (out.has_reference_time) {
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
        const double s2 = marks_[m].survey_sigma_m * marks_[m].survey_sigma_m +
                          config_.min_prediction_sigma_m * config_.min_prediction_sigma_m;
        w.pred[m].p = w.T_w_b[b] * marks_[m].p_body;
        w.pred[m].cov =
            point_covariance(w.T_w_b[b], marks_[m].p_body, w.cov_b[b]) + s2 * Mat3::Identity();
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
  finish_exposure(w, t_s, out);
  for (size_t b = 0; b < bodies_.size(); ++b) {
    if (w.reacquired[b]) refused_in_a_row_[b] = 0;
    if (!w.search_refused[b]) continue;
    const int doublings = std::min(refused_in_a_row_[b]++, MatcherConfig::kMaxRetryDoublings);
    next_search_s_[b] = t_s + config_.reacquisition_retry_s * static_cast<double>(1 << doublings);
  }
  accumulate(w.counts);
}

MatchResult MarkMatcher::estimate_identified(std::span<const msg::MarkObservations> cameras,
                                             const std::vector<std::vector<int>>& ids) {
  if (ids.size() != cameras.size())
    throw std::invalid_argument("MarkMatcher::estimate_identified: one id list per camera");
  Work& w = *work_.work;
  MatchResult out;
  const double t_s = begin_exposure(w, cameras, out);
  // Assign the given ids; an id twice in one camera is an identification ambiguity: neither.
  std::vector<int>* members = nullptr;
  for (int o = 0; o < static_cast<int>(w.obs.size()); ++o) {
    Work::Obs& ob = w.obs[o];
    const auto& given = ids[ob.span_index];
    if (ob.mark_index >= static_cast<int>(given.size()))
      throw std::invalid_argument("MarkMatcher::estimate_identified: ids shorter than mark_count");
    const int id = given[ob.mark_index];
    if (id < 0) continue;
    const auto it = std::lower_bound(marks_.begin(), marks_.end(), id,
                                     [](const MarkInfo& mi, int v) { return mi.id < v; });
    if (it != marks_.end() && it->id == id) {
      ob.mark = static_cast<int>(it - marks_.begin());
      members = &w.assigned[ob.mark];
    } else {
      auto other = std::find_if(w.others.begin(), w.others.end(),
                                [id](const Work::OtherMark& x) { return x.id == id; });
      if (other == w.others.end()) {
        w.others.emplace_back();
        w.others.back().id = id;
        other = w.others.end() - 1;
      }
      members = &other->obs;
    }
    const auto same_camera = [&](int k) { return w.obs[k].cam == ob.cam; };
    if (std::any_of(members->begin(), members->end(), same_camera)) {
      ++w.counts.duplicate_id;
      for (int k : *members)
        if (same_camera(k)) w.obs[k].state = ObsState::kAmbiguous;
      std::erase_if(*members, same_camera);
      ob.state = ObsState::kAmbiguous;
      continue;
    }
    // Ambiguous already (a third sighting in that camera): stays out.
    if (ob.state == ObsState::kAmbiguous) continue;
    ob.state = ObsState::kAssigned;
    members->push_back(o);
  }
  for (auto& ob : w.obs)
    if (ob.state == ObsState::kAmbiguous) ob.mark = -1;
  for (int m = 0; m < static_cast<int>(marks_.size()); ++m)
    if (w.assigned[m].size() >= 2 && triangulate_identified(w, m, w.assigned[m]))
      w.tri[m].accept(w.tri_result);
  for (Work::OtherMark& other : w.others) {
    ++w.counts.given_ids_of_no_body;
    if (other.obs.size() >= 2 && triangulate_identified(w, -1, other.obs))
      other.tri.accept(w.tri_result);
  }
  for (int m = 0; m < static_cast<int>(marks_.size()); ++m)
    if (w.assigned[m].size() == 1) ++w.counts.single_view;
  finish_exposure(w, t_s, out);
  accumulate(w.counts);
  return out;
}

bool MarkMatcher::triangulate_identified(Work& w, int m, std::span<const int> obs) const {
  // Weights at the prediction when the tracks give one (as the gates do), else at the linear
  // point; then THE triangulation (verification.cpp) without a test.
  std::optional<Vec3> at;
  if (m >= 0 && w.pred[m].valid) at = w.pred[m].p;
  if (!at) {
    auto& views = w.tri_views;
    views.clear();
    for (int o : obs) {
      const auto& cal = rig_.cameras[w.obs[o].slot];
      triangulate::Observation v;
      v.model = &cal.model;
      v.T_c_w = cal.T_c_w;
      v.pixel_px = w.obs[o].raw;
      views.push_back(v);
    }
    at = triangulate::triangulate_linear(views);
  }
  bool ok = at.has_value();
  for (int o : obs) {
    if (!ok) break;
    auto& ob = w.obs[o];
    if (config_.use_calibration_covariance)
      ok = uncertainty::view_information(factors_, ob.slot, rig_.cameras[ob.slot], *at, ob.sigma,
                                         ob.W);
    else
      ob.W = Mat2::Identity() / (ob.sigma * ob.sigma);
  }
  if (!ok || !triangulate(w, m, obs, *at)) {
    ++w.counts.triangulation_failed;
    return false;
  }
  return true;
}

void MarkMatcher::finish_exposure(Work& w, double t_s, MatchResult& out) {
  // Hands each accepted estimate over to the result (swapped: the storage stays in use).
  auto add_mark = [&](int id, int body, PredictionSource source, std::vector<int>& as,
                      Work::Tri& tri, const Work::Motion& motion) {
    std::sort(as.begin(), as.end());  // camera order (the estimate's views are in it already)
    MatchedMark& mm = out.marks.emplace_back();
    if (!w.spare_marks.empty()) {
      mm = std::move(w.spare_marks.back());  // every field is set below
      w.spare_marks.pop_back();
    }
    mm.id = id;
    mm.body = body;
    mm.source = source;
    mm.observations.clear();
    for (int o : as) {
      const auto& ob = w.obs[o];
      const auto& cal = rig_.cameras[ob.slot];
      mm.observations.push_back({cal.camera_id, ob.span_index, ob.mark_index, ob.raw, ob.sigma,
                                 ob.W, w.cams[ob.cam].dt_s});
      out.ids[ob.span_index][ob.mark_index] = id;
    }
    mm.triangulated = tri.valid;
    if (tri.valid)
      std::swap(mm.estimate, tri.estimate);
    else
      mm.estimate.clear();
    mm.velocity_w = motion.v_w;
    mm.velocity_valid = motion.valid;
    mm.motion_corrected = motion.valid;
    out.identified += static_cast<int>(as.size());
  };
  for (size_t m = 0; m < marks_.size(); ++m) {
    auto& as = w.assigned[m];
    if (as.empty()) continue;
    Work::Motion motion = w.motion[m];
    const MarkTrack& mt = mark_tracks_[m];
    if (!motion.valid && w.tri[m].valid && mt.count > 0) {
      // Second exposure of a track: the velocity from the previous position states the
      // time-offset uncertainty; this estimate stays uncorrected (at rest: no bias).
      const double dt = t_s - mt.t_s[mt.count - 1];
      if (dt > 0 && dt <= config_.track_max_gap_s) {
        add_mark(marks_[m].id, marks_[m].body, w.pred[m].source, as, w.tri[m], {});
        out.marks.back().velocity_w = (w.tri[m].p - mt.p_w[mt.count - 1]) / dt;
        out.marks.back().velocity_valid = true;
        continue;
      }
    }
    add_mark(marks_[m].id, marks_[m].body, w.pred[m].source, as, w.tri[m], motion);
  }
  for (Work::OtherMark& other : w.others)
    if (!other.obs.empty())
      add_mark(other.id, -1, PredictionSource::kNone, other.obs, other.tri, {});
  std::sort(out.marks.begin(), out.marks.end(),
            [](const MatchedMark& a, const MatchedMark& b) { return a.id < b.id; });
  w.counts.identified += static_cast<std::uint64_t>(out.identified);
  out.acquired_from_prior = w.acquired;
  if (w.acquired) ++w.counts.acquisitions;
  out.T_w_b = w.T_w_b;
  out.cov_b = w.cov_b;
  out.fitted = w.fitted;
  out.reacquired = w.reacquired;
  if (out.has_reference_time) update_tracks(w, t_s);
}

void MarkMatcher::accumulate(const MatchCounters& d) {
  auto& c = counters_;
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
  c.duplicate_id += d.duplicate_id;
  c.given_ids_of_no_body += d.given_ids_of_no_body;
  c.triangulation_failed += d.triangulation_failed;
}

}  // namespace storetrack::match
