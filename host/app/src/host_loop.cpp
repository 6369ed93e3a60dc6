#include "host_loop.hpp"

#include <poll.h>

#include <spdlog/spdlog.h>
#include <algorithm>
#include <cerrno>
#include <cinttypes>
#include <cstdio>
#include <cstring>

#include "diagnostic_csv.hpp"
#include "host_setup.hpp"

namespace storetrack::hostapp {

HostLoop::HostLoop(const LoopParts& parts) : p_(parts), aligner_(*parts.chain.aligner) {}

void HostLoop::on_message(const msg::AnyMessage& m) {
  if (const auto* obs = std::get_if<msg::MarkObservations>(&m)) {
    if (t_first_input_ == 0) t_first_input_ = now_;
    t_last_input_ = now_;
    aligner_.push(*obs, now_, ready_);
  } else if (const auto* h = std::get_if<msg::UnitHealth>(&m)) {
    ++totals_.health_messages;
    totals_.unit_health[h->unit_id] = {
        {"clock_state", h->clock_state},       {"frames_captured", h->frames_captured},
        {"frames_dropped", h->frames_dropped}, {"observations_sent", h->observations_sent},
        {"link_tx_errors", h->link_tx_errors}, {"status", h->status}};
    if (p_.live) p_.live->on_health(*h, now_);
  }
}

// The calibration health test's news (docs/calibration-health.md): a camera whose baseline ended
// unmonitored, a camera declared moved, the processor rebuilt on the corrected rig.
void HostLoop::log_calibration_health(const pipeline::AlignedExposure& e, bool processor_rebuilt) {
  const pipeline::CalibrationHealthGuard& guard = *p_.chain.health;
  const auto& cams = guard.monitor().cameras();
  health_reported_.resize(cams.size(), false);
  for (std::size_t s = 0; s < cams.size(); ++s) {
    const pipeline::CameraHealth& h = cams[s];
    if (h.baseline_done && !health_reported_[s]) {
      health_reported_[s] = true;
      if (!h.monitored)
        spdlog::warn(
            "calibration health: camera {} is not monitored ({} pylon marks in its baseline, "
            "{} needed, or not in calibration_health.cameras)",
            h.camera_id, h.pylon_marks, guard.monitor().config().min_pylon_marks);
    }
    if (h.moved && h.first_alarm_exposure == guard.monitor().exposures() && h.alarms == 1)
      spdlog::error(
          "calibration health: camera {} declared MOVED at trigger_seq {} (statistic {:.1f} > "
          "{:.1f}): rotation [{:.3f} {:.3f} {:.3f}] mrad, translation [{:.3f} {:.3f} {:.3f}] mm "
          "(camera frame, since the baseline; from a window partly before the move)",
          h.camera_id, e.trigger_seq, h.last_statistic, guard.monitor().threshold(),
          h.motion(0) * 1e3, h.motion(1) * 1e3, h.motion(2) * 1e3, h.motion(3) * 1e3,
          h.motion(4) * 1e3, h.motion(5) * 1e3);
  }
  if (processor_rebuilt)
    spdlog::warn("calibration health: processor rebuilt on the corrected rig (correction {})",
                 guard.counters().corrections);
}

// The clearance alarm's start and end (docs/clearance.md, "In the host"): one log line each.
void HostLoop::log_clearance(const pipeline::ExposureResult& r) {
  const clearance::SampleClearance& c = *p_.chain.clearance;
  if (!(r.T_p_s.valid || r.extrapolated) || !c.alarm_changed()) return;  // not evaluated, or same
  const msg::FtiSample& s = r.sample;
  if (c.alarm())
    spdlog::error(
        "clearance ALARM from trigger_seq {}: store to {} lower bound (k=2) {:.4f} m < {:.4f} m "
        "(distance {:.4f} m, u {:.4f} m)",
        r.trigger_seq, c.model().aircraft_part_name(s.clearance_part), s.clearance_lower_bound_m,
        c.alarm_threshold_m(), s.clearance_m, s.u_clearance_m);
  else
    spdlog::warn("clearance alarm ended at trigger_seq {}: lower bound (k=2) {:.4f} m to {}",
                 r.trigger_seq, s.clearance_lower_bound_m,
                 c.model().aircraft_part_name(s.clearance_part));
}

void HostLoop::process(const pipeline::AlignedExposure& exposure) {
  const time::MonotonicNs t0 = time::monotonic_now_ns();
  // exclude's filter, matcher, geometry, extrapolation over short gaps, the sample, the
  // calibration health test.
  const ProcessedExposure done = process_exposure(p_.chain, exposure);
  const pipeline::AlignedExposure& e = *done.exposure;
  const pipeline::ExposureResult& r = done.result;
  if (p_.chain.health) log_calibration_health(e, done.processor_rebuilt);
  if (p_.chain.clearance) log_clearance(r);
  ++totals_.exposures;
  // No output, iNET-X or file, carries an exposure too few cameras measured.
  const bool written =
      totals_.withheld.admit(judge_sample(r.cameras_used, aligner_.config().min_cameras));
  if (written) write_sample(done, t0);
  // After the outputs, so the page's copy is never in the latency; at most once per interval.
  if (p_.live) {
    const live::LiveTotals live_totals{totals_.exposures, totals_.samples_written,
                                       totals_.valid_samples, totals_.withheld.total(),
                                       totals_.health_messages};
    p_.live->on_exposure(e, r, written, aligner_, live_totals, time::monotonic_now_ns());
  }
}

void HostLoop::write_sample(const ProcessedExposure& done, time::MonotonicNs t_processing_start) {
  const pipeline::AlignedExposure& e = *done.exposure;
  const pipeline::ExposureResult& r = done.result;
  ++totals_.samples_written;
  const msg::FtiSample& s = r.sample;
  if (s.status & msg::fti_status::kValid) ++totals_.valid_samples;
  if (p_.inetx) p_.inetx->send(s);
  const time::MonotonicNs t_sent = time::monotonic_now_ns();
  totals_.latency_processing.add(t_sent - t_processing_start);
  // From the exposure's last observation in (the aligner's clock, this loop's now_) to sent:
  // keyed by the exposure itself, so a unit renumbering its exposures cannot mix them up.
  if (e.last_arrival_mono_ns > 0) {
    const time::MonotonicNs latency = t_sent - e.last_arrival_mono_ns;
    totals_.latency_all.add(latency);
    if (e.missing_camera_mask == 0) totals_.latency_complete.add(latency);
  }
  if (!p_.recording.has_files()) return;
  RecordingItem item;
  item.sample = s;
  if (p_.recording.wants_marks_rows()) format_marks_rows(e, r, item.marks_rows);
  if (p_.recording.wants_rigid_rows()) {
    format_rigid_rows(e.trigger_seq, 'p', r.pylon_check, item.rigid_rows);
    format_rigid_rows(e.trigger_seq, 's', r.store_check, item.rigid_rows);
  }
  if (p_.recording.wants_clearance_rows() && done.clearance_evaluated)
    format_clearance_rows(s, done.clearance_extrapolated, *p_.chain.clearance, item.clearance_rows);
  p_.recording.push(std::move(item));  // never blocks; a full queue is counted there
}

// The aligner's inputs besides the messages, in the raw channel in their order: a replay that
// gives the aligner the same messages and events at the same times releases the same exposures.
void HostLoop::record_aligner_event(ingest::RawSourceKind kind, time::MonotonicNs t) {
  if (!p_.recording.wants_raw()) return;
  msg::RawObservation r{};
  r.source_kind = static_cast<std::uint8_t>(kind);
  r.arrival_tai_ns = time::tai_now_ns();
  r.unit_id = 0xFF;
  r.camera_id = 0xFF;
  r.flags = msg::raw_observation_flags::kAccepted;  // given to the aligner
  r.host_mono_ns = t;
  p_.recording.push_raw(r, {});
}

void HostLoop::process_ready() {
  for (const auto& e : ready_)
    process(e);
  ready_.clear();
}

int HostLoop::run(const LoopLimits& limits, const std::atomic<bool>& stop) {
  std::vector<pollfd> fds;
  if (p_.udp.fd() >= 0) fds.push_back({p_.udp.fd(), POLLIN, 0});
  for (const auto& c : p_.cans)
    fds.push_back({c->fd(), POLLIN, 0});
  auto handler = [this](const msg::AnyMessage& m) { on_message(m); };
  // Every observation message as received, valid or not, into the raw channel.
  if (p_.recording.wants_raw()) {
    auto raw = [this](const msg::RawObservation& r, std::span<const std::uint8_t> bytes) {
      msg::RawObservation timed = r;
      timed.host_mono_ns = now_;  // the time on_message gives the aligner with this message
      p_.recording.push_raw(timed, bytes);  // never blocks; a full queue is counted there
    };
    p_.udp.set_raw_handler(raw);
    for (auto& c : p_.cans)
      c->set_raw_handler(raw);
  }
  const time::MonotonicNs t_start = time::monotonic_now_ns();
  time::MonotonicNs t_last_progress = t_start;
  int exit_code = 0;
  while (!stop) {
    now_ = time::monotonic_now_ns();
    const time::MonotonicNs deadline = aligner_.next_deadline();
    int timeout_ms = 100;
    if (deadline != INT64_MAX)
      timeout_ms = static_cast<int>(
          std::clamp<std::int64_t>((deadline - now_ + 999'999) / 1'000'000, 0, 100));
    const int n = ::poll(fds.data(), fds.size(), timeout_ms);
    if (n < 0 && errno != EINTR) {
      spdlog::error("poll: {}", std::strerror(errno));
      exit_code = 1;
      break;
    }
    now_ = time::monotonic_now_ns();
    std::size_t fi = 0;
    if (p_.udp.fd() >= 0) {
      if (fds[fi].revents & POLLIN) p_.udp.receive(handler);
      ++fi;
    }
    for (auto& c : p_.cans) {
      if (fds[fi].revents & POLLIN)
        c->receive(handler);
      else
        c->expire(now_);
      ++fi;
    }
    const time::MonotonicNs t_poll = time::monotonic_now_ns();
    if (aligner_.poll(t_poll, ready_))
      record_aligner_event(ingest::RawSourceKind::kAlignerDeadline, t_poll);
    process_ready();
    now_ = time::monotonic_now_ns();
    if (limits.progress && now_ - t_last_progress >= 1'000'000'000) {
      t_last_progress = now_;
      std::fprintf(stderr,
                   "\rstoretrack-host: %" PRIu64 " exposures, %" PRIu64 " valid, pending %zu   ",
                   totals_.exposures, totals_.valid_samples, aligner_.pending());
    }
    if (limits.duration_s > 0 &&
        now_ - t_start >= static_cast<std::int64_t>(limits.duration_s * 1e9))
      break;
    if (limits.idle_exit_s > 0 && t_first_input_ != 0 &&
        now_ - t_last_input_ >= static_cast<std::int64_t>(limits.idle_exit_s * 1e9))
      break;
    if (limits.expect_exposures > 0 &&
        static_cast<std::int64_t>(totals_.exposures) >= limits.expect_exposures)
      break;
  }
  aligner_.flush(ready_);
  record_aligner_event(ingest::RawSourceKind::kAlignerFlush, time::monotonic_now_ns());
  process_ready();
  if (limits.progress) std::fprintf(stderr, "\n");
  return exit_code;
}

}  // namespace storetrack::hostapp
