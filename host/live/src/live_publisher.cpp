#include <algorithm>
#include <stdexcept>
#include <string>

#include "storetrack/live/live_snapshot.hpp"

namespace storetrack::live {

LivePublisher::LivePublisher(const LiveRig& rig, time::MonotonicNs min_interval_ns)
    : rig_(rig), min_interval_ns_(min_interval_ns) {
  if (rig.camera_ids.size() > static_cast<std::size_t>(kMaxLiveCameras))
    throw std::invalid_argument("live view: " + std::to_string(rig.camera_ids.size()) +
                                " cameras, at most " + std::to_string(kMaxLiveCameras));
  if (rig.unit_ids.size() != rig.camera_ids.size())
    throw std::invalid_argument("live view: one unit id per camera expected");
  for (int unit : rig.unit_ids) {
    const auto end = units_.begin() + unit_count_;
    if (std::find_if(units_.begin(), end,
                     [unit](const LiveUnit& u) { return u.unit_id == unit; }) != end)
      continue;
    units_[static_cast<std::size_t>(unit_count_++)].unit_id = unit;
  }
}

void LivePublisher::on_health(const msg::UnitHealth& health, time::MonotonicNs now) {
  for (int i = 0; i < unit_count_; ++i) {
    LiveUnit& u = units_[static_cast<std::size_t>(i)];
    if (u.unit_id != health.unit_id) continue;
    u.heard = true;
    u.health = health;
    u.heard_mono_ns = now;
    ++u.messages;
    return;
  }
  ++health_unknown_unit_;
}

bool LivePublisher::on_exposure(const pipeline::AlignedExposure& exposure,
                                const pipeline::ExposureResult& result, bool sample_written,
                                const ingest::ExposureAligner& aligner, const LiveTotals& totals,
                                time::MonotonicNs now) {
  // Carried on every exposure, so a publication shows the newest sample and poses even when
  // the exposures between publications were not copied.
  if (sample_written) {
    has_sample_ = true;
    sample_ = result.sample;
  }
  if (result.T_w_p.valid) pylon_ = {true, exposure.trigger_seq, result.T_w_p.T};
  if (result.T_w_s.valid) store_ = {true, exposure.trigger_seq, result.T_w_s.T};
  for (const msg::MarkObservations& obs : exposure.cameras) {
    for (std::size_t c = 0; c < rig_.camera_ids.size(); ++c) {
      if (rig_.camera_ids[c] != obs.camera_id) continue;
      last_seen_[c] = {obs.clock_state, now};
      break;
    }
  }
  if (publications_ > 0 && now - last_publication_ns_ < min_interval_ns_) return false;
  last_publication_ns_ = now;
  fill(buffer_.back(), exposure, result, sample_written, aligner, totals, now);
  buffer_.publish();
  ++publications_;
  return true;
}

void LivePublisher::fill(LiveSnapshot& s, const pipeline::AlignedExposure& exposure,
                         const pipeline::ExposureResult& result, bool sample_written,
                         const ingest::ExposureAligner& aligner, const LiveTotals& totals,
                         time::MonotonicNs now) const {
  s.publication = publications_ + 1;
  s.published_mono_ns = now;
  s.trigger_seq = exposure.trigger_seq;
  s.exposure_mid_tai_ns = exposure.exposure_mid_tai_ns;
  s.missing_camera_mask = exposure.missing_camera_mask;
  s.closed_by_timeout = exposure.closed_by_timeout;
  s.cameras_used = result.cameras_used;
  s.sample_written = sample_written;
  s.camera_count = static_cast<int>(rig_.camera_ids.size());
  const auto& camera_counters = aligner.camera_counters();
  for (int c = 0; c < s.camera_count; ++c) {
    LiveCamera& cam = s.cameras[static_cast<std::size_t>(c)];
    cam = LiveCamera{};
    cam.camera_id = rig_.camera_ids[static_cast<std::size_t>(c)];
    cam.unit_id = rig_.unit_ids[static_cast<std::size_t>(c)];
    cam.last_clock_state = last_seen_[static_cast<std::size_t>(c)].clock_state;
    cam.last_seen_mono_ns = last_seen_[static_cast<std::size_t>(c)].mono_ns;
    if (static_cast<std::size_t>(c) < camera_counters.size())
      cam.counters = camera_counters[static_cast<std::size_t>(c)];
    for (const msg::MarkObservations& obs : exposure.cameras) {
      if (obs.camera_id != cam.camera_id) continue;
      cam.delivered = true;
      cam.trigger_seq = obs.trigger_seq;
      cam.exposure_start_tai_ns = obs.exposure_start_tai_ns;
      cam.exposure_duration_ns = obs.exposure_duration_ns;
      cam.clock_state = obs.clock_state;
      cam.flags = obs.flags;
      cam.mark_count = std::min<int>(obs.mark_count, kMaxLiveMarks);  // decoders refuse > 64
      for (int j = 0; j < cam.mark_count; ++j) {
        const auto& m = obs.marks[static_cast<std::size_t>(j)];
        cam.marks[static_cast<std::size_t>(j)].x_px = m.x_px;
        cam.marks[static_cast<std::size_t>(j)].y_px = m.y_px;
      }
    }
  }
  // Identities and residuals from the matcher's triangulated marks.
  for (const pipeline::MarkResult& mark : result.marks) {
    for (const auto& o : mark.observations) {
      for (int c = 0; c < s.camera_count; ++c) {
        LiveCamera& cam = s.cameras[static_cast<std::size_t>(c)];
        if (cam.camera_id != o.camera_id || o.mark_index < 0 || o.mark_index >= cam.mark_count)
          continue;
        LiveMark& lm = cam.marks[static_cast<std::size_t>(o.mark_index)];
        lm.id = static_cast<std::int16_t>(std::clamp(mark.id, -1, 32767));
        lm.body = mark.body;
        lm.excluded = mark.excluded;
        lm.has_residual = true;
        lm.residual_x_px = static_cast<float>(o.residual_px.x());
        lm.residual_y_px = static_cast<float>(o.residual_px.y());
      }
    }
  }
  s.unit_count = unit_count_;
  s.units = units_;
  s.aligner = aligner.counters();
  s.totals = totals;
  s.has_sample = has_sample_;
  s.sample = sample_;
  s.pylon = pylon_;
  s.store = store_;
}

}  // namespace storetrack::live
