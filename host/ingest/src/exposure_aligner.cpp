#include "storetrack/ingest/exposure_aligner.hpp"

#include <algorithm>
#include <bit>
#include <climits>
#include <stdexcept>

namespace storetrack::ingest {

ExposureAligner::ExposureAligner(AlignerConfig config) : config_(std::move(config)) {
  if (config_.camera_ids.empty() || config_.camera_ids.size() > 32)
    throw std::invalid_argument("ExposureAligner: the rig needs 1..32 cameras");
  if (config_.max_wait_ns <= 0) throw std::invalid_argument("ExposureAligner: max_wait_ns <= 0");
  if (config_.max_pending == 0) config_.max_pending = 1;
  all_mask_ =
      config_.camera_ids.size() == 32 ? 0xFFFFFFFFu : ((1u << config_.camera_ids.size()) - 1u);
  camera_counters_.resize(config_.camera_ids.size());
  history_key_.fill(INT64_MIN);
}

int ExposureAligner::camera_index(int camera_id) const {
  for (std::size_t i = 0; i < config_.camera_ids.size(); ++i)
    if (config_.camera_ids[i] == camera_id) return static_cast<int>(i);
  return -1;
}

std::int64_t ExposureAligner::unwrap(std::uint32_t seq) const {
  // Serial-number arithmetic (RFC 1982): the nearest 64-bit value congruent to seq.
  const auto delta = static_cast<std::int32_t>(seq - static_cast<std::uint32_t>(newest_seen_));
  return newest_seen_ + delta;
}

void ExposureAligner::remember_released(std::int64_t key, std::uint32_t mask) {
  const std::size_t slot = static_cast<std::size_t>(key) % kHistory;
  history_key_[slot] = key;
  history_mask_[slot] = mask;
}

void ExposureAligner::push(const msg::MarkObservations& obs, time::MonotonicNs now,
                           std::vector<pipeline::AlignedExposure>& out) {
  ++counters_.observations_in;
  const int cam = camera_index(obs.camera_id);
  if (cam < 0) {
    ++counters_.dropped_unknown_camera;
    return;
  }
  CameraCounters& cc = camera_counters_[static_cast<std::size_t>(cam)];
  ++cc.received;
  if (obs.trigger_seq == 0xFFFFFFFFu || obs.exposure_start_tai_ns == INT64_MIN ||
      obs.mark_count > obs.marks.size()) {
    ++counters_.dropped_invalid;
    return;
  }
  if (!have_reference_) {
    have_reference_ = true;
    newest_seen_ = obs.trigger_seq;
  }
  std::int64_t key = unwrap(obs.trigger_seq);
  if (released_any_ && key <= released_through_ - config_.sequence_restart_threshold) {
    // The trigger source restarted (sequence went far back): close the old run and start anew.
    ++counters_.sequence_restarts;
    flush(out);
    released_any_ = false;
    history_key_.fill(INT64_MIN);
    newest_seen_ = obs.trigger_seq;
    key = obs.trigger_seq;
  }
  const std::uint32_t bit = 1u << cam;
  if (released_any_ && key <= released_through_) {
    const std::size_t slot = static_cast<std::size_t>(key) % kHistory;
    if (history_key_[slot] == key && (history_mask_[slot] & bit)) {
      ++counters_.dropped_duplicate;
      ++cc.duplicate;
    } else {
      ++counters_.dropped_late;
      ++cc.late;
    }
    return;
  }
  newest_seen_ = std::max(newest_seen_, key);
  const time::TaiNs mid = pipeline::exposure_mid_tai_ns(obs);
  auto [it, inserted] = pending_.try_emplace(key);
  Pending& p = it->second;
  if (inserted) {
    p.first_arrival = now;
    p.reference_mid_tai_ns = mid;
    p.cameras.reserve(config_.camera_ids.size());
  } else {
    if (p.present_mask & bit) {
      ++counters_.dropped_duplicate;
      ++cc.duplicate;
      return;
    }
    const std::int64_t spread = mid - p.reference_mid_tai_ns;
    if (spread > config_.max_mid_time_spread_ns || spread < -config_.max_mid_time_spread_ns) {
      ++counters_.dropped_time_mismatch;
      ++cc.time_mismatch;
      return;
    }
  }
  p.cameras.push_back(obs);
  p.present_mask |= bit;
  ++counters_.observations_used;
  ++cc.used;
  while (pending_.size() > config_.max_pending)
    release(pending_.begin(), ReleaseReason::kOverflow, out);
  release_ready(now, out);
}

void ExposureAligner::poll(time::MonotonicNs now, std::vector<pipeline::AlignedExposure>& out) {
  release_ready(now, out);
}

void ExposureAligner::flush(std::vector<pipeline::AlignedExposure>& out) {
  while (!pending_.empty())
    release(pending_.begin(), ReleaseReason::kFlush, out);
}

time::MonotonicNs ExposureAligner::next_deadline() const {
  time::MonotonicNs earliest = INT64_MAX;
  for (const auto& [key, p] : pending_)
    earliest = std::min(earliest, p.first_arrival + config_.max_wait_ns);
  return earliest;
}

void ExposureAligner::release_ready(time::MonotonicNs now,
                                    std::vector<pipeline::AlignedExposure>& out) {
  // In sequence order: an exposure waits for older ones (each bounded by its own deadline), so
  // the processor's tracking always sees time move forward. A timed-out exposure also releases
  // everything older than it, whatever their own deadlines.
  auto newest_expired = pending_.end();
  for (auto it = pending_.begin(); it != pending_.end(); ++it)
    if (now - it->second.first_arrival >= config_.max_wait_ns) newest_expired = it;
  while (!pending_.empty()) {
    auto it = pending_.begin();
    const bool complete = it->second.present_mask == all_mask_;
    const bool forced = newest_expired != pending_.end() && it->first <= newest_expired->first;
    if (!complete && !forced) break;
    if (newest_expired == it) newest_expired = pending_.end();
    release(it, complete ? ReleaseReason::kComplete : ReleaseReason::kTimeout, out);
  }
}

void ExposureAligner::release(std::map<std::int64_t, Pending>::iterator it, ReleaseReason reason,
                              std::vector<pipeline::AlignedExposure>& out) {
  const std::int64_t key = it->first;
  Pending& p = it->second;
  const std::uint32_t missing = all_mask_ & ~p.present_mask;
  released_through_ = released_any_ ? std::max(released_through_, key) : key;
  released_any_ = true;
  remember_released(key, p.present_mask);
  for (std::size_t i = 0; i < config_.camera_ids.size(); ++i)
    if (missing & (1u << i)) ++camera_counters_[i].missing;
  const int delivered = static_cast<int>(p.cameras.size());
  if (delivered < config_.min_cameras) {
    ++counters_.exposures_dropped_too_few_cameras;
    pending_.erase(it);
    return;
  }
  switch (reason) {
    case ReleaseReason::kComplete:
      ++counters_.exposures_complete;
      break;
    case ReleaseReason::kOverflow:
      ++counters_.exposures_partial_overflow;
      break;
    case ReleaseReason::kTimeout:
    case ReleaseReason::kFlush:
      if (missing == 0)
        ++counters_.exposures_complete;
      else
        ++counters_.exposures_partial_timeout;
      break;
  }
  counters_.camera_missing_total += static_cast<std::uint64_t>(std::popcount(missing));
  pipeline::AlignedExposure e;
  e.trigger_seq = static_cast<std::uint32_t>(key);
  e.missing_camera_mask = missing;
  e.closed_by_timeout = missing != 0;
  time::TaiNs earliest_start = INT64_MAX;
  for (const auto& o : p.cameras) {
    if (o.exposure_start_tai_ns < earliest_start) {
      earliest_start = o.exposure_start_tai_ns;
      e.exposure_mid_tai_ns = pipeline::exposure_mid_tai_ns(o);
    }
  }
  e.cameras = std::move(p.cameras);
  pending_.erase(it);
  out.push_back(std::move(e));
}

}  // namespace storetrack::ingest
