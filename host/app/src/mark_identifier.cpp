#include "mark_identifier.hpp"

#include <algorithm>
#include <limits>

namespace storetrack::hostapp {

MarkIdentifier::MarkIdentifier(const camera::RigCalibration& rig, const sim::RigidBodySurvey& pylon,
                               const sim::RigidBodySurvey& store, IdentifierConfig config)
    : rig_(rig), pylon_(pylon), store_(store), config_(config) {
  for (const auto& m : pylon_.marks)
    ids_.push_back(m.id);
  for (const auto& m : store_.marks)
    ids_.push_back(m.id);
}

void MarkIdentifier::set_initial_positions(const std::map<int, geometry::Vec3>& p_w_by_id) {
  initial_ = p_w_by_id;
}

bool MarkIdentifier::predict(int id, time::TaiNs t, geometry::Vec3& p_w) const {
  if (auto it = tracks_.find(id); it != tracks_.end() && it->second.valid) {
    const double dt = static_cast<double>(t - it->second.t) * 1e-9;
    if (dt >= 0 && dt <= config_.max_track_age_s) {
      p_w = it->second.p_w;
      if (it->second.v_valid) p_w += it->second.v_w * dt;
      return true;
    }
  }
  if (const auto* m = pylon_.find(id); m && have_T_w_p_) {
    p_w = T_w_p_ * m->p_body;
    return true;
  }
  if (const auto* m = store_.find(id); m && have_T_w_s_) {
    p_w = T_w_s_ * m->p_body;
    return true;
  }
  if (auto it = initial_.find(id); it != initial_.end()) {
    p_w = it->second;
    return true;
  }
  return false;
}

pipeline::MarkIds MarkIdentifier::identify(const pipeline::AlignedExposure& exposure) {
  pipeline::MarkIds ids(exposure.cameras.size());
  std::vector<int> pred_id;
  std::vector<geometry::Vec3> pred_w;
  for (int id : ids_) {
    geometry::Vec3 p;
    if (predict(id, exposure.exposure_mid_tai_ns, p)) {
      pred_id.push_back(id);
      pred_w.push_back(p);
    }
  }
  if (pred_id.empty()) ++counters_.no_prediction;
  std::vector<geometry::Vec2> pred_px;
  std::vector<bool> pred_ok;
  for (std::size_t e = 0; e < exposure.cameras.size(); ++e) {
    const auto& obs = exposure.cameras[e];
    ids[e].assign(obs.mark_count, -1);
    counters_.observations += obs.mark_count;
    const camera::CalibratedCamera* cam = rig_.find(obs.camera_id);
    if (!cam) continue;
    pred_px.assign(pred_id.size(), geometry::Vec2::Zero());
    pred_ok.assign(pred_id.size(), false);
    for (std::size_t i = 0; i < pred_id.size(); ++i) {
      if (auto px = cam->model.project_world(cam->T_c_w, pred_w[i])) {
        pred_px[i] = *px;
        pred_ok[i] = true;
      }
    }
    std::map<int, int> claimed;  // mark id -> observation index (-2: conflict)
    for (int j = 0; j < obs.mark_count; ++j) {
      const geometry::Vec2 z(obs.marks[static_cast<std::size_t>(j)].x_px,
                             obs.marks[static_cast<std::size_t>(j)].y_px);
      double best = std::numeric_limits<double>::infinity(), second = best;
      int best_i = -1;
      for (std::size_t i = 0; i < pred_id.size(); ++i) {
        if (!pred_ok[i]) continue;
        const double d = (pred_px[i] - z).norm();
        if (d < best) {
          second = best;
          best = d;
          best_i = static_cast<int>(i);
        } else if (d < second) {
          second = d;
        }
      }
      if (best_i < 0 || best > config_.gate_px) {
        ++counters_.unmatched;
        continue;
      }
      if (second < config_.ambiguity_ratio * std::max(best, 0.5) && second < 3 * config_.gate_px) {
        ++counters_.ambiguous;
        continue;
      }
      const int id = pred_id[static_cast<std::size_t>(best_i)];
      auto [it, inserted] = claimed.try_emplace(id, j);
      if (!inserted) {
        if (it->second >= 0) {
          ids[e][static_cast<std::size_t>(it->second)] = -1;
          --counters_.identified;
          ++counters_.conflicts;
        }
        it->second = -2;
        ++counters_.conflicts;
        continue;
      }
      ids[e][static_cast<std::size_t>(j)] = id;
      ++counters_.identified;
    }
  }
  return ids;
}

void MarkIdentifier::update(const pipeline::ExposureResult& result, time::TaiNs t) {
  for (const auto& m : result.marks) {
    if (m.excluded) continue;
    Track& tr = tracks_[m.id];
    if (tr.valid) {
      const double dt = static_cast<double>(t - tr.t) * 1e-9;
      if (dt > 0 && dt <= config_.max_track_age_s) {
        tr.v_w = (m.p_w - tr.p_w) / dt;
        tr.v_valid = true;
      } else {
        tr.v_valid = false;
      }
    }
    tr.valid = true;
    tr.t = t;
    tr.p_w = m.p_w;
  }
  if (result.T_w_p.valid) {
    have_T_w_p_ = true;
    T_w_p_ = result.T_w_p.T;
  }
  if (result.T_w_s.valid) {
    have_T_w_s_ = true;
    T_w_s_ = result.T_w_s.T;
  }
}

}  // namespace storetrack::hostapp
