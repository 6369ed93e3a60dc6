#include "storetrack/ingest/exposure_aligner.hpp"

#include <algorithm>
#include <bit>
#include <climits>
#include <iterator>
#include <stdexcept>
#include <string>

#include "storetrack/time/saturating.hpp"

namespace storetrack::ingest {
namespace {

std::int64_t abs_diff(std::int64_t a, std::int64_t b) {
  const std::int64_t d = time::saturating_sub_ns(a, b);
  return d == INT64_MIN ? INT64_MAX : (d < 0 ? -d : d);
}

void require(bool ok, const std::string& field, const std::string& range) {
  if (!ok) throw std::invalid_argument("ExposureAligner: " + field + " must be " + range);
}

void validate(const AlignerConfig& c) {
  require(!c.camera_ids.empty() && c.camera_ids.size() <= kMaxAlignerCameras, "camera_ids",
          "1..32 cameras (the rig)");
  require(c.unit_ids.empty() || c.unit_ids.size() == c.camera_ids.size(), "unit_ids",
          "empty or one per camera");
  require(c.max_wait_ns > 0 && c.max_wait_ns <= kMaxAlignerWaitNs, "max_wait_ns", "in (0, 60 s]");
  require(c.max_mid_time_spread_ns >= 0 && c.max_mid_time_spread_ns <= kMaxMidTimeSpreadNs,
          "max_mid_time_spread_ns", "in [0, 1 s]");
  require(c.max_pending >= 1 && c.max_pending <= kMaxAlignerPending, "max_pending", "1..4096");
  require(c.min_cameras >= 1 && static_cast<std::size_t>(c.min_cameras) <= c.camera_ids.size(),
          "min_cameras", "1..the number of rig cameras");
  require(c.max_sequence_lead >= 1 && c.max_sequence_lead <= kMaxSequenceLead, "max_sequence_lead",
          "1..100000");
}

}  // namespace

ExposureAligner::ExposureAligner(AlignerConfig config) : config_(std::move(config)) {
  validate(config_);
  const std::size_t n = config_.camera_ids.size();
  all_mask_ = n == 32 ? 0xFFFFFFFFu : ((1u << n) - 1u);
  restart_quorum_ = n / 2 + 1;  // a strict majority of the rig
  camera_counters_.resize(n);
  cameras_.resize(n);
}

int ExposureAligner::camera_index(int camera_id) const {
  for (std::size_t i = 0; i < config_.camera_ids.size(); ++i)
    if (config_.camera_ids[i] == camera_id) return static_cast<int>(i);
  return -1;
}

std::size_t ExposureAligner::held() const {
  return static_cast<std::size_t>(std::count_if(cameras_.begin(), cameras_.end(),
                                                [](const CameraState& c) { return c.holding; }));
}

std::int64_t ExposureAligner::unwrap(const CameraState& cs, std::uint32_t seq) const {
  // Serial-number arithmetic (RFC 1982): the nearest 64-bit value congruent to seq.
  const auto delta = static_cast<std::int32_t>(seq - static_cast<std::uint32_t>(cs.last_unwrapped));
  return cs.last_unwrapped + delta;
}

const ExposureAligner::Released* ExposureAligner::released_entry(std::int64_t key) const {
  const auto h = static_cast<std::int64_t>(kHistory);
  const Released& r = history_[static_cast<std::size_t>(((key % h) + h) % h)];
  return r.key == key ? &r : nullptr;
}

void ExposureAligner::remember_released(std::int64_t key, std::uint32_t mask, time::TaiNs mid) {
  const auto h = static_cast<std::int64_t>(kHistory);
  history_[static_cast<std::size_t>(((key % h) + h) % h)] = {key, mask, mid};
}

bool ExposureAligner::accept_fields(const msg::MarkObservations& obs, int cam) {
  CameraCounters& cc = camera_counters_[static_cast<std::size_t>(cam)];
  if (!config_.unit_ids.empty() && config_.unit_ids[static_cast<std::size_t>(cam)] != obs.unit_id) {
    ++counters_.dropped_spoofed;
    ++cc.spoofed;
    return false;
  }
  if (obs.trigger_seq == msg::mark_observations_invalid::kTriggerSeq ||
      obs.exposure_start_tai_ns == msg::mark_observations_invalid::kExposureStartTaiNs ||
      obs.mark_count > obs.marks.size()) {
    ++counters_.dropped_invalid;
    return false;
  }
  // Refused, not saturated: a start time this far out is no exposure of this flight, and inside
  // the range every mid-time sum and difference below fits int64.
  if (obs.exposure_start_tai_ns < 0 || obs.exposure_start_tai_ns > kMaxExposureStartTaiNs) {
    ++counters_.dropped_time_out_of_range;
    return false;
  }
  return true;
}

void ExposureAligner::push(const msg::MarkObservations& obs, time::MonotonicNs now,
                           std::vector<pipeline::AlignedExposure>& out) {
  ++counters_.observations_in;
  const int cam = camera_index(obs.camera_id);
  if (cam < 0) {
    ++counters_.dropped_unknown_camera;
    return;
  }
  ++camera_counters_[static_cast<std::size_t>(cam)].received;
  if (!accept_fields(obs, cam)) return;
  if (delivered_before(cam, obs)) {
    ++counters_.dropped_duplicate;
    ++camera_counters_[static_cast<std::size_t>(cam)].duplicate;
    return;
  }
  place(cam, obs, now);
  while (pending_.size() > config_.max_pending)
    release(pending_.begin(), ReleaseReason::kOverflow, out);
  release_ready(now, out);
}

std::optional<time::TaiNs> ExposureAligner::grid_mid(std::int64_t key) const {
  if (!released_any_ || grid_period_ns_ <= 0) return std::nullopt;
  const std::int64_t d = key - grid_key_;
  if (d > (1 << 20) || d < -(1 << 20)) return std::nullopt;
  return grid_mid_ + d * grid_period_ns_;
}

std::optional<std::int64_t> ExposureAligner::exposure_at_time(time::TaiNs mid) const {
  // The exposure whose mid-time this is: a pending one, a recently released one, or a slot of
  // the trigger grid not yet opened but within the lead window. Nothing further: a clock that
  // jumped by seconds must not look like a sequence offset.
  std::optional<std::int64_t> best;
  std::int64_t best_err = match_tolerance();
  auto consider = [&](std::int64_t key, time::TaiNs ref) {
    const std::int64_t err = abs_diff(mid, ref);
    if (err <= best_err) {
      best = key;
      best_err = err;
    }
  };
  for (const auto& [key, p] : pending_)
    consider(key, p.reference_mid_tai_ns);
  if (released_any_)
    for (std::int64_t k = released_through_ - kRecentReleased + 1; k <= released_through_; ++k)
      if (const Released* r = released_entry(k)) consider(k, r->mid);
  if (released_any_ && grid_period_ns_ > 0) {
    const std::int64_t offset = time::saturating_sub_ns(mid, grid_mid_);
    const std::int64_t half = grid_period_ns_ / 2;
    const std::int64_t d = (offset >= 0 ? offset + half : offset - half) / grid_period_ns_;
    const std::int64_t k = grid_key_ + d;
    const auto predicted = grid_mid(k);
    if (predicted && k > released_through_ && k <= newest_key_ + lead_limit() &&
        pending_.find(k) == pending_.end())
      consider(k, *predicted);
  }
  return best;
}

std::int64_t ExposureAligner::lead_limit() const {
  // The units' latency differences, in exposures: a fixed time, not the wait (a 5 s wait would
  // make a datagram 2000 exposures ahead look like a camera legitimately ahead). Before the
  // period is measured, the fastest trigger is assumed.
  const auto configured = static_cast<std::int64_t>(config_.max_sequence_lead);
  const std::int64_t period = grid_period_ns_ > 0 ? grid_period_ns_ : kFastestTriggerPeriodNs;
  const std::int64_t window_ns = std::min(config_.max_wait_ns, kMaxLeadTimeNs);
  return std::max<std::int64_t>(1, std::min(configured, window_ns / period));
}

bool ExposureAligner::continues_own_stream(int cam, std::int64_t key, time::MonotonicNs now) const {
  // A jump ahead of the newest exposure that the camera's own stream explains: no further than
  // the trigger can have run (one exposure per period) since its newest placed observation
  // arrived, plus the lead window. One datagram from the future, arriving now, is not.
  const CameraState& cs = cameras_[static_cast<std::size_t>(cam)];
  if (!cs.placed_any) return false;
  const std::int64_t period = grid_period_ns_ > 0 ? grid_period_ns_ : kFastestTriggerPeriodNs;
  const std::int64_t elapsed =
      std::max<std::int64_t>(0, time::saturating_sub_ns(now, cs.frontier_arrival));
  const std::int64_t ran = std::min<std::int64_t>(
      elapsed / period, static_cast<std::int64_t>(config_.max_sequence_lead));
  return key - cs.frontier_key <= lead_limit() + ran;
}

bool ExposureAligner::on_grid_over_gap(std::int64_t key, time::TaiNs mid) const {
  // The period is measured over a few exposures: its error, extrapolated over a gap, grows with
  // the gap (allowed: 1/64 of a period per exposure), still far below the hundreds of periods a
  // glitched sequence with the current time is off by.
  const auto predicted = grid_mid(key);
  if (!predicted || key <= grid_key_ || key - newest_key_ > config_.max_sequence_lead) return false;
  const std::int64_t tolerance = match_tolerance() + (key - grid_key_) * (grid_period_ns_ / 64);
  return abs_diff(mid, *predicted) <= tolerance;
}

bool ExposureAligner::gap_explained(std::int64_t key, time::TaiNs mid,
                                    time::MonotonicNs now) const {
  // A jump ahead past the lead window, as when every camera's datagrams were lost together: its
  // time lies on the grid at its sequence, and it does not arrive before it could have (a forged
  // or glitched datagram consistent with a future edge arrives that far early).
  // The tolerance is the lead window's time, not the wait.
  const time::MonotonicNs baseline = std::min(lag_min_current_, lag_min_previous_);
  if (baseline == INT64_MAX) return false;
  const time::MonotonicNs tolerance = std::min(config_.max_wait_ns, kMaxLeadTimeNs);
  return on_grid_over_gap(key, mid) &&
         time::saturating_sub_ns(now, mid) >= time::saturating_sub_ns(baseline, tolerance);
}

bool ExposureAligner::held_on_grid(int cam) const {
  const CameraState& cs = cameras_[static_cast<std::size_t>(cam)];
  const std::int64_t key = unwrap(cs, cs.held.trigger_seq) + cs.offset;
  return have_key_ && key > newest_key_ &&
         on_grid_over_gap(key, pipeline::exposure_mid_tai_ns(cs.held));
}

bool ExposureAligner::on_grid(std::int64_t key, time::TaiNs mid) const {
  const auto predicted = grid_mid(key);
  return !predicted || abs_diff(mid, *predicted) <= config_.max_mid_time_spread_ns;
}

bool ExposureAligner::in_time_order(std::int64_t key, time::TaiNs mid) const {
  // Exposures k < k' start at least (k' - k) periods of the fastest trigger apart, within the
  // spread: checked against every pending exposure not opened by one camera alone unjudged (a
  // lone first datagram may be the wrong one) and against the newest released exposure.
  const auto ordered = [&](std::int64_t other_key, time::TaiNs other_mid) {
    const std::int64_t keys_apart = key - other_key;
    if (keys_apart == 0) return true;
    const std::int64_t later = keys_apart > 0 ? time::saturating_sub_ns(mid, other_mid)
                                              : time::saturating_sub_ns(other_mid, mid);
    const std::int64_t exposures = keys_apart > 0 ? keys_apart : -keys_apart;
    // Capped at the longest wait's worth of periods: far apart, order is all that is checked,
    // and a forged key's distance times the period cannot overflow.
    const std::int64_t at_least =
        std::min<std::int64_t>(exposures, kMaxAlignerWaitNs / kFastestTriggerPeriodNs) *
        kFastestTriggerPeriodNs;
    return later >= at_least - config_.max_mid_time_spread_ns;
  };
  for (const auto& [other_key, p] : pending_)
    if (!lone_unjudged(p) && !ordered(other_key, p.reference_mid_tai_ns)) return false;
  if (const Released* r = released_any_ ? released_entry(released_through_) : nullptr)
    if (!ordered(r->key, r->mid)) return false;
  return true;
}

std::int64_t ExposureAligner::match_tolerance() const {
  // Identifying an exposure by time needs a tolerance below half the period, whatever the
  // configured spread: a quarter period leaves margin for the units' latency differences.
  if (grid_period_ns_ <= 0) return config_.max_mid_time_spread_ns;
  return std::min(config_.max_mid_time_spread_ns, grid_period_ns_ / 4);
}

bool ExposureAligner::clock_stepped(const CameraState& cs, const msg::MarkObservations& obs) const {
  // The unit's TAI moved against its own monotonic clock since this camera last agreed with the
  // majority: its time is what is wrong, not its sequence.
  if (!cs.have_clock_baseline ||
      obs.exposure_start_mono_ns == msg::mark_observations_invalid::kExposureStartMonoNs)
    return false;
  const std::int64_t tai_minus_mono =
      time::saturating_sub_ns(obs.exposure_start_tai_ns, obs.exposure_start_mono_ns);
  return abs_diff(tai_minus_mono, cs.tai_minus_mono_ns) > match_tolerance();
}

void ExposureAligner::place(int cam, const msg::MarkObservations& obs, time::MonotonicNs now,
                            bool gap_confirmed) {
  CameraState& cs = cameras_[static_cast<std::size_t>(cam)];
  if (!cs.seen) {
    cs.seen = true;
    cs.last_unwrapped = obs.trigger_seq;  // offset 0: the rig shares one trigger sequence
  }
  const std::int64_t unwrapped = unwrap(cs, obs.trigger_seq);
  const std::int64_t key = unwrapped + cs.offset;
  const time::TaiNs mid = pipeline::exposure_mid_tai_ns(obs);
  const auto names_other_exposure = [&] {
    const auto other = exposure_at_time(mid);
    return other && *other != key;
  };
  auto it = pending_.find(key);
  const bool released = it == pending_.end() && released_any_ && key <= released_through_;
  const Released* entry = released ? released_entry(key) : nullptr;
  // Does the sequence name a place an exposure can be (pending, a released one still in the
  // history, or a new one the others can reach within the wait), and does the time agree?
  bool plausible = true, time_agrees = true;
  Opening opening = Opening::kJudged;
  if (it != pending_.end()) {
    time_agrees = abs_diff(mid, it->second.reference_mid_tai_ns) <= config_.max_mid_time_spread_ns;
  } else if (released) {
    plausible = released_through_ - key < static_cast<std::int64_t>(kHistory);
    time_agrees = entry && abs_diff(mid, entry->mid) <= config_.max_mid_time_spread_ns;
  } else {
    // A new exposure, anywhere (ahead, in a gap, behind the oldest pending): its time must not
    // be another exposure's. An offset re-learned since (a restart) maps a replayed datagram
    // onto a new index; opening it would release that exposure a second time.
    // Past the lead window: the camera's own stream or a majority holding the same gap judge
    // the jump; the grid and the arrival time alone let it open an exposure that other cameras
    // must confirm. The first datagram of a run has nothing to be judged by.
    if (!have_key_) opening = Opening::kFirstOfRun;
    if (have_key_ && key - newest_key_ > lead_limit() && !gap_confirmed &&
        !continues_own_stream(cam, key, now)) {
      opening = Opening::kByArrivalTime;
      plausible = gap_explained(key, mid, now);
    }
    time_agrees = on_grid(key, mid) && !names_other_exposure();
    // A sequence whose exposure cannot lie where its time is among the exposures several
    // cameras hold (a unit renumbered from 0, heard by a fresh host before the grid is known):
    // the sequence is what is wrong, unless the unit's clock stepped.
    if (!in_time_order(key, mid) && !clock_stepped(cs, obs)) plausible = false;
  }
  // A disagreeing time is a clock fault (the majority judges it at release) when the unit's
  // TAI stepped, or when it names no other exposure; otherwise the sequence is what is wrong.
  const bool fits = plausible && (time_agrees || clock_stepped(cs, obs) || !names_other_exposure());
  if (!fits) {
    quarantine(cam, obs, unwrapped, now);
    return;
  }
  if (cs.holding) drop_held(cam);  // the sequence fits again: the held one was a lone glitch
  cs.last_unwrapped = std::max(cs.last_unwrapped, unwrapped);
  if (released) {
    drop_known(key, cam);
    return;
  }
  if (it == pending_.end()) {
    if (have_key_ && newest_key_ - key > lead_limit()) evict_lone_exposures_ahead_of(key);
    it = pending_.try_emplace(key).first;
    it->second.first_arrival = now;
    it->second.opening = opening;
    it->second.cameras.reserve(config_.camera_ids.size());
    newest_key_ = have_key_ ? std::max(newest_key_, key) : key;
    have_key_ = true;
  }
  add_to_pending(it, cam, obs, now);
}

void ExposureAligner::add_to_pending(PendingMap::iterator it, int cam,
                                     const msg::MarkObservations& obs, time::MonotonicNs now) {
  Pending& p = it->second;
  const std::uint32_t bit = 1u << cam;
  if (p.present_mask & bit) {
    ++counters_.dropped_duplicate;
    ++camera_counters_[static_cast<std::size_t>(cam)].duplicate;
    return;
  }
  p.cameras.push_back(obs);
  p.present_mask |= bit;
  p.last_arrival = std::max(p.last_arrival, now);
  CameraState& cs = cameras_[static_cast<std::size_t>(cam)];
  if (cs.placements_with_offset++ == 0) note_rig_numbering();
  if (!cs.placed_any || it->first >= cs.frontier_key) {
    cs.placed_any = true;
    cs.frontier_key = it->first;
    cs.frontier_arrival = now;
  }
  advance_stream_clock(now);
  if (p.cameras.size() == 1) p.stream_ns_at_open = stream_ns_;
  remember_delivered(cam, obs);
  const Majority m = majority(p.cameras, it->first);
  p.reference_mid_tai_ns = pipeline::exposure_mid_tai_ns(p.cameras[m.reference]);
}

bool ExposureAligner::delivered_before(int cam, const msg::MarkObservations& obs) const {
  // A camera never starts two exposures at one instant: the same sequence and start again is a
  // repeated datagram, whatever the rest of it (a corrupted duration moves its mid-time by
  // seconds, out of reach of every check by time).
  const CameraState& cs = cameras_[static_cast<std::size_t>(cam)];
  return cs.delivered.count({obs.trigger_seq, obs.exposure_start_tai_ns}) != 0;
}

void ExposureAligner::remember_delivered(int cam, const msg::MarkObservations& obs) {
  CameraState& cs = cameras_[static_cast<std::size_t>(cam)];
  const DeliveredId id{obs.trigger_seq, obs.exposure_start_tai_ns};
  if (!cs.delivered.insert(id).second) return;
  cs.delivered_order.push_back(id);
  if (cs.delivered_order.size() > kRecentDelivered) {
    cs.delivered.erase(cs.delivered_order.front());
    cs.delivered_order.pop_front();
  }
}

bool ExposureAligner::lone_unjudged(const Pending& p) const {
  return all_mask_ != 1u && p.opening != Opening::kJudged && std::popcount(p.present_mask) == 1;
}

// Takes back an exposure that one camera opened and no other confirmed: its observation is
// counted as quarantined, and is no longer "delivered" (the camera's true observation of that
// exposure is still to come) nor the camera's newest.
void ExposureAligner::take_back(PendingMap::iterator it) {
  const auto cam = static_cast<std::size_t>(std::countr_zero(it->second.present_mask));
  CameraState& cs = cameras_[cam];
  const msg::MarkObservations& o = it->second.cameras.front();
  const DeliveredId id{o.trigger_seq, o.exposure_start_tai_ns};
  if (cs.delivered.erase(id) != 0)
    cs.delivered_order.erase(std::find(cs.delivered_order.begin(), cs.delivered_order.end(), id));
  if (cs.placed_any && cs.frontier_key == it->first) cs.placed_any = false;
  if (cs.placements_with_offset > 0 && unwrap(cs, o.trigger_seq) + cs.offset == it->first)
    --cs.placements_with_offset;
  ++counters_.dropped_quarantined;
  ++camera_counters_[cam].quarantined;
  pending_.erase(it);
}

void ExposureAligner::recompute_newest_key(std::int64_t floor_key) {
  newest_key_ = floor_key;
  if (!pending_.empty()) newest_key_ = std::max(newest_key_, std::prev(pending_.end())->first);
  if (released_any_) newest_key_ = std::max(newest_key_, released_through_);
}

// A fitting observation more than the lead window behind the newest exposure: newer exposures
// that one camera opened unconfirmed (the first datagram of a run, or a jump accepted by grid
// and arrival time alone: forged or glitched far ahead) are taken back, so they cannot hold the
// newest index. Exposures a camera's own stream or several cameras opened stay.
void ExposureAligner::evict_lone_exposures_ahead_of(std::int64_t key) {
  auto it = pending_.end();
  while (it != pending_.begin()) {
    const auto before = std::prev(it);
    if (before->first - key <= lead_limit()) break;
    if (lone_unjudged(before->second))
      take_back(before);  // `it` stays valid: a map erases only the element
    else
      it = before;
  }
  recompute_newest_key(key);
}

bool ExposureAligner::take_back_expired_unconfirmed(time::MonotonicNs now) {
  // An unconfirmed exposure whose wait ended is never released: released, it would make every
  // exposure before it late, and become a sample no other camera took.
  bool taken = false;
  for (auto it = pending_.begin(); it != pending_.end();) {
    const auto next = std::next(it);
    if (lone_unjudged(it->second) && it->second.opening == Opening::kByArrivalTime &&
        now >= deadline_of(it->second)) {
      take_back(it);
      taken = true;
    }
    it = next;
  }
  if (taken && (!pending_.empty() || released_any_)) recompute_newest_key(INT64_MIN);
  return taken;
}

void ExposureAligner::drop_known(std::int64_t key, int cam) {
  CameraCounters& cc = camera_counters_[static_cast<std::size_t>(cam)];
  const Released* r = released_entry(key);
  if (r && (r->mask & (1u << cam))) {
    ++counters_.dropped_duplicate;
    ++cc.duplicate;
  } else {
    ++counters_.dropped_late;
    ++cc.late;
  }
}

void ExposureAligner::drop_held(int cam) {
  CameraState& cs = cameras_[static_cast<std::size_t>(cam)];
  if (!cs.holding) return;
  cs.holding = false;
  ++counters_.dropped_quarantined;
  ++camera_counters_[static_cast<std::size_t>(cam)].quarantined;
}

void ExposureAligner::quarantine(int cam, const msg::MarkObservations& obs, std::int64_t unwrapped,
                                 time::MonotonicNs now) {
  CameraState& cs = cameras_[static_cast<std::size_t>(cam)];
  const auto target = exposure_at_time(pipeline::exposure_mid_tai_ns(obs));
  std::optional<std::int64_t> implied;
  if (target) implied = *target - unwrapped;
  // Two different exposures, in time order: a duplicated datagram held twice proves nothing.
  const bool follows_held =
      cs.holding && obs.trigger_seq != cs.held.trigger_seq &&
      pipeline::exposure_mid_tai_ns(obs) > pipeline::exposure_mid_tai_ns(cs.held);
  // An offset the camera already has explains nothing new: they did not fit with it (placing
  // them again would quarantine them again, without end).
  if (implied && follows_held && cs.held_offset == implied && *implied != cs.offset) {
    // Two observations in a row agree on where this camera's sequence now sits (a restarted
    // unit, a re-numbered trigger): re-learn the offset and place both.
    cs.offset = *implied;
    cs.placements_with_offset = 0;
    cs.last_unwrapped = unwrapped;
    cs.holding = false;
    ++counters_.sequence_offset_changes;
    CameraCounters& cc = camera_counters_[static_cast<std::size_t>(cam)];
    ++cc.offset_changes;
    cc.sequence_offset = cs.offset;
    const msg::MarkObservations held = cs.held;
    place(cam, held, now);
    place(cam, obs, now);
    return;
  }
  drop_held(cam);
  cs.holding = true;
  cs.held = obs;
  cs.held_offset = implied;
  if (!implied) try_trigger_restart(now);
}

void ExposureAligner::try_trigger_restart(time::MonotonicNs now) {
  // Held observations that no exposure explains, agreeing in time with the newest one: when a
  // majority of the rig holds them, the trigger itself restarted (or jumped): open a new
  // exposure for them after the newest, and a new grid.
  std::vector<int> agreeing;
  time::TaiNs reference = 0;
  bool have_reference = false;
  for (std::size_t i = 0; i < cameras_.size(); ++i) {
    const CameraState& cs = cameras_[i];
    if (!cs.holding || cs.held_offset) continue;
    const time::TaiNs mid = pipeline::exposure_mid_tai_ns(cs.held);
    // A restarted trigger renumbers, but time goes on: an observation that started before the
    // newest released exposure's mid-time is a replay (a duplicated or long-delayed datagram),
    // not a restart. Its start, not its mid-time: a corrupted duration moves the mid-time.
    if (released_any_ && cs.held.exposure_start_tai_ns <= newest_released_mid_) continue;
    if (!have_reference) {
      reference = mid;
      have_reference = true;
    }
    if (abs_diff(mid, reference) <= config_.max_mid_time_spread_ns)
      agreeing.push_back(static_cast<int>(i));
  }
  if (agreeing.size() < restart_quorum_ || restarting_) return;
  restarting_ = true;  // placing the held ones may quarantine again: no nested restart
  // A restart renumbers the trigger: time and sequence no longer agree with the grid. A
  // majority whose sequences still lie on the grid lost datagrams together: a gap.
  if (std::all_of(agreeing.begin(), agreeing.end(), [&](int cam) { return held_on_grid(cam); })) {
    for (const int cam : agreeing) {
      CameraState& cs = cameras_[static_cast<std::size_t>(cam)];
      cs.holding = false;
      const msg::MarkObservations held = cs.held;
      place(cam, held, now, true);
    }
    restarting_ = false;
    return;
  }
  ++counters_.sequence_restarts;
  const std::int64_t new_key = newest_key_ + 1;
  grid_period_ns_ = 0;  // a new trigger: learn its period again
  for (const int cam : agreeing) {
    CameraState& cs = cameras_[static_cast<std::size_t>(cam)];
    const std::int64_t unwrapped = unwrap(cs, cs.held.trigger_seq);
    cs.offset = new_key - unwrapped;
    cs.placements_with_offset = 0;
    cs.last_unwrapped = unwrapped;
    cs.holding = false;
    camera_counters_[static_cast<std::size_t>(cam)].sequence_offset = cs.offset;
    const msg::MarkObservations held = cs.held;
    place(cam, held, now);
  }
  restarting_ = false;
}

std::size_t ExposureAligner::numbering_votes(std::int64_t offset) const {
  return static_cast<std::size_t>(std::count_if(
      cameras_.begin(), cameras_.end(),
      [&](const CameraState& cs) { return cs.placements_with_offset > 0 && cs.offset == offset; }));
}

ExposureAligner::NumberingVote ExposureAligner::numbering_vote() const {
  // Over cameras that placed an observation with their current offset: a camera still in
  // another numbering, not yet re-learned, has no say. Among numberings with as many cameras,
  // the leader is the one that counted the most trigger edges (the smallest offset).
  NumberingVote v;
  for (const CameraState& candidate : cameras_) {
    if (candidate.placements_with_offset == 0 || candidate.offset == v.leader) continue;
    const std::size_t votes = numbering_votes(candidate.offset);
    if (votes > v.votes) {
      v.leader = candidate.offset;
      v.votes = votes;
      v.tied = false;
    } else if (votes == v.votes) {
      v.tied = true;
      v.leader = std::min(*v.leader, candidate.offset);
    }
  }
  return v;
}

void ExposureAligner::note_rig_numbering() {
  // Chosen when one numbering leads with two cameras or more (a lone camera heard first is no
  // evidence: it may be the renumbered one), or with the one camera of a one-camera rig.
  const NumberingVote v = numbering_vote();
  if (v.leader && !v.tied && (v.votes >= 2 || cameras_.size() == 1)) rig_offset_ = v.leader;
}

std::optional<std::uint32_t> ExposureAligner::rig_sequence(std::int64_t key) {
  // The numbering most cameras of the rig share. Not the sequences of this exposure's own
  // cameras: with one camera of each numbering a vote among them is a tie, and a host restarted
  // behind a unit renumbered from 0 would index its exposures by whichever camera it heard first
  // (the fault campaign's duplicate numbers). Once chosen it is kept until another numbering
  // leads with two cameras or more: a camera whose unit renumbers is re-learned onto the same
  // exposure indices, so the rig's numbering goes on when no camera carries it any more (the
  // last camera that did restarted from 0). Before any choice (a fresh host that heard one
  // camera of each numbering), the one that counted the most edges: a restarted unit counts
  // from 0, so the largest sequence is the unit that ran longest, the rig's own unless every
  // unit restarted since the trigger started. One camera heard alone numbers its exposure but is
  // not remembered: it may be the renumbered one.
  note_rig_numbering();
  std::optional<std::int64_t> offset = rig_offset_;
  if (!offset) {
    const NumberingVote v = numbering_vote();
    offset = v.leader;
    if (v.tied) rig_offset_ = v.leader;
  }
  if (!offset) return std::nullopt;
  return static_cast<std::uint32_t>(key - *offset);
}

ExposureAligner::Majority ExposureAligner::majority(
    const std::vector<msg::MarkObservations>& cameras, std::int64_t key) const {
  // The mid-time most cameras agree with (within the spread); a tie goes to the one nearest the
  // trigger grid's prediction. Never simply the first to arrive.
  const auto predicted = grid_mid(key);
  Majority best;
  int best_count = -1;
  std::int64_t best_err = INT64_MAX;
  for (std::size_t i = 0; i < cameras.size(); ++i) {
    const time::TaiNs mid_i = pipeline::exposure_mid_tai_ns(cameras[i]);
    std::uint32_t mask = 0;
    for (std::size_t j = 0; j < cameras.size(); ++j)
      if (abs_diff(pipeline::exposure_mid_tai_ns(cameras[j]), mid_i) <=
          config_.max_mid_time_spread_ns)
        mask |= 1u << j;
    const int count = std::popcount(mask);
    const std::int64_t err = predicted ? abs_diff(mid_i, *predicted) : 0;
    if (count > best_count || (count == best_count && err < best_err)) {
      best = {mask, i};
      best_count = count;
      best_err = err;
    }
  }
  return best;
}

bool ExposureAligner::poll(time::MonotonicNs now, std::vector<pipeline::AlignedExposure>& out) {
  return release_ready(now, out);
}

void ExposureAligner::flush(std::vector<pipeline::AlignedExposure>& out) {
  while (!pending_.empty()) {
    const Pending& p = pending_.begin()->second;
    if (lone_unjudged(p) && p.opening == Opening::kByArrivalTime)
      take_back(pending_.begin());
    else
      release(pending_.begin(), ReleaseReason::kFlush, out);
  }
  for (std::size_t i = 0; i < cameras_.size(); ++i)
    drop_held(static_cast<int>(i));
}

void ExposureAligner::advance_stream_clock(time::MonotonicNs now) {
  // Host time while observations keep being placed; a silence longer than half the wait (a
  // stalled host, a paused rig) does not count. Only placed observations: a flood of quarantined
  // or foreign datagrams keeps no exposure waiting.
  const time::MonotonicNs gap = time::saturating_sub_ns(now, last_placed_);
  if (last_placed_ != INT64_MIN && gap > 0 && gap <= config_.max_wait_ns / 2) stream_ns_ += gap;
  last_placed_ = now;
}

time::MonotonicNs ExposureAligner::deadline_of(const Pending& p) const {
  // The wait, from the exposure's first arrival, counts once observations went on being placed
  // for the wait (the stream clock, without silences) or nothing was placed for the wait: a
  // host reading its socket's backlog after a stall has a clock far ahead of the datagrams'.
  const time::MonotonicNs waited = time::saturating_add_ns(p.first_arrival, config_.max_wait_ns);
  if (stream_ns_ - p.stream_ns_at_open >= config_.max_wait_ns) return waited;
  return std::max(waited, time::saturating_add_ns(last_placed_, config_.max_wait_ns));
}

bool ExposureAligner::forces_older(const Pending& p) const {
  return all_mask_ == 1u || std::popcount(p.present_mask) >= 2;
}

time::MonotonicNs ExposureAligner::next_deadline() const {
  // The deadlines that make something happen: the oldest exposure's, those that force older ones
  // out, and those of unconfirmed exposures (taken back). A lone exposure behind the oldest waits
  // for it whatever its own deadline says.
  time::MonotonicNs earliest = INT64_MAX;
  for (auto it = pending_.begin(); it != pending_.end(); ++it) {
    const Pending& p = it->second;
    if (it == pending_.begin() || forces_older(p) ||
        (lone_unjudged(p) && p.opening == Opening::kByArrivalTime))
      earliest = std::min(earliest, deadline_of(p));
  }
  return earliest;
}

bool ExposureAligner::release_ready(time::MonotonicNs now,
                                    std::vector<pipeline::AlignedExposure>& out) {
  // In sequence order: an exposure waits for older ones (each bounded by its own deadline), so
  // the processor's tracking always sees time move forward. A timed-out exposure also releases
  // everything older than it, whatever their own deadlines (a release moves no deadline).
  // Only an exposure of two cameras or more forces older ones out: a single camera never
  // releases or times out the other cameras' exposures (a lone one waits for them, then goes).
  bool changed = take_back_expired_unconfirmed(now);
  auto newest_expired = pending_.end();
  for (auto it = pending_.begin(); it != pending_.end(); ++it)
    if (now >= deadline_of(it->second) && forces_older(it->second)) newest_expired = it;
  while (!pending_.empty()) {
    auto it = pending_.begin();
    const bool complete = it->second.present_mask == all_mask_;
    const bool forced = newest_expired != pending_.end() && it->first <= newest_expired->first;
    if (!complete && !forced && now < deadline_of(it->second)) break;
    if (newest_expired == it) newest_expired = pending_.end();
    release(it, complete ? ReleaseReason::kComplete : ReleaseReason::kTimeout, out);
    changed = true;
  }
  return changed;
}

void ExposureAligner::update_lag_baseline(const Pending& p, time::TaiNs reference_mid,
                                          int agreeing_cameras) {
  if (static_cast<std::size_t>(agreeing_cameras) < restart_quorum_) return;
  lag_min_current_ =
      std::min(lag_min_current_, time::saturating_sub_ns(p.first_arrival, reference_mid));
  if (++lag_window_releases_ < kHistory) return;
  lag_min_previous_ = lag_min_current_;
  lag_min_current_ = INT64_MAX;
  lag_window_releases_ = 0;
}

void ExposureAligner::update_grid(std::int64_t key, time::TaiNs mid, int agreeing_cameras) {
  if (!released_any_) {
    grid_key_ = key;
    grid_mid_ = mid;
    return;
  }
  const std::int64_t d = key - grid_key_;
  if (d <= 0) return;
  // A lone camera off the grid (a clock that jumped) does not move it; a few in a row do.
  const auto predicted = grid_mid(key);
  if (predicted && abs_diff(mid, *predicted) > config_.max_mid_time_spread_ns &&
      agreeing_cameras < 2 && ++grid_misses_ < 4)
    return;
  grid_misses_ = 0;
  if (d <= 64) {
    const std::int64_t period = (mid - grid_mid_) / d;
    if (period > 0 && period <= time::kNsPerSecond) grid_period_ns_ = period;
  }
  grid_key_ = key;
  grid_mid_ = mid;
}

void ExposureAligner::release(PendingMap::iterator it, ReleaseReason reason,
                              std::vector<pipeline::AlignedExposure>& out) {
  const std::int64_t key = it->first;
  Pending& p = it->second;
  const Majority m = majority(p.cameras, key);
  const time::TaiNs reference_mid = pipeline::exposure_mid_tai_ns(p.cameras[m.reference]);
  const time::MonotonicNs last_arrival = p.last_arrival;
  std::vector<msg::MarkObservations> kept;
  kept.reserve(p.cameras.size());
  std::uint32_t present = 0;
  for (std::size_t j = 0; j < p.cameras.size(); ++j) {
    const msg::MarkObservations& o = p.cameras[j];
    const int cam = camera_index(o.camera_id);
    if (m.inlier_mask & (1u << j)) {
      kept.push_back(o);
      present |= 1u << cam;
      CameraState& cs = cameras_[static_cast<std::size_t>(cam)];
      if (o.exposure_start_mono_ns != msg::mark_observations_invalid::kExposureStartMonoNs) {
        cs.tai_minus_mono_ns =
            time::saturating_sub_ns(o.exposure_start_tai_ns, o.exposure_start_mono_ns);
        cs.have_clock_baseline = true;
      }
    } else {
      ++counters_.dropped_time_mismatch;
      ++camera_counters_[static_cast<std::size_t>(cam)].time_mismatch;
    }
  }
  update_lag_baseline(p, reference_mid, std::popcount(present));
  pending_.erase(it);
  const std::uint32_t missing = all_mask_ & ~present;
  update_grid(key, reference_mid, std::popcount(present));
  released_through_ = released_any_ ? std::max(released_through_, key) : key;
  released_any_ = true;
  newest_released_mid_ = std::max(newest_released_mid_, reference_mid);
  remember_released(key, present, reference_mid);
  for (std::size_t i = 0; i < config_.camera_ids.size(); ++i)
    if (missing & (1u << i)) ++camera_counters_[i].missing;
  if (static_cast<int>(kept.size()) < config_.min_cameras) {
    ++counters_.exposures_dropped_too_few_cameras;
    counters_.dropped_too_few_cameras += kept.size();
    return;
  }
  const std::optional<std::uint32_t> trigger_seq = rig_sequence(key);
  if (!trigger_seq) {
    ++counters_.exposures_dropped_numbering_unknown;
    counters_.dropped_numbering_unknown += kept.size();
    return;
  }
  counters_.observations_used += kept.size();
  for (const auto& o : kept)
    ++camera_counters_[static_cast<std::size_t>(camera_index(o.camera_id))].used;
  if (reason == ReleaseReason::kOverflow)
    ++counters_.exposures_partial_overflow;
  else if (missing == 0)
    ++counters_.exposures_complete;
  else
    ++counters_.exposures_partial_timeout;
  counters_.camera_missing_total += static_cast<std::uint64_t>(std::popcount(missing));
  pipeline::AlignedExposure e;
  e.trigger_seq = *trigger_seq;
  e.missing_camera_mask = missing;
  e.closed_by_timeout = missing != 0;
  e.last_arrival_mono_ns = last_arrival;
  time::TaiNs earliest_start = INT64_MAX;
  for (const auto& o : kept) {
    if (o.exposure_start_tai_ns < earliest_start) {
      earliest_start = o.exposure_start_tai_ns;
      e.exposure_mid_tai_ns = pipeline::exposure_mid_tai_ns(o);
    }
  }
  e.cameras = std::move(kept);
  out.push_back(std::move(e));
}

}  // namespace storetrack::ingest
