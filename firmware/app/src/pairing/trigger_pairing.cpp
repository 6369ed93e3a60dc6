#include "pairing/trigger_pairing.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <nlohmann/json.hpp>

namespace storetrack::unit {

bool TriggerPairing::configure(const TriggerConfig& config, std::string& error) {
  const auto period = static_cast<std::int64_t>(std::llround(1e9 / config.rate_hz));
  config_.period_ns = period;
  config_.latency_ns = config.latency_ns;
  config_.match_tolerance_ns =
      config.match_tolerance_ns > 0 ? config.match_tolerance_ns : period / 4;
  config_.edge_phase_tolerance_ns =
      config.edge_phase_tolerance_ns > 0 ? config.edge_phase_tolerance_ns : period / 4;
  config_.trigger_to_exposure_ns = config.trigger_to_exposure_ns;
  triggered_only_ = config.triggered_only;
  const char* why = nullptr;
  if (trigger::validate(config_, &why) < 0) {
    error = std::string("trigger pairing: ") + why;
    return false;
  }
  return true;
}

void TriggerPairing::start(std::uint32_t first_sequence) {
  config_.first_sequence = first_sequence;
  pairer_.emplace(config_);
}

int TriggerPairing::drain(Trigger& trigger, int timeout_ms) {
  if (!pairer_) return 0;
  int retries_left = 1;
  for (;;) {
    const int n = trigger.line().read_edges(edges_, timeout_ms);
    if (n < 0 && n != -EAGAIN && n != -EINTR) {
      ++read_errors_;
      if (retries_left-- > 0) continue;
    }
    if (n <= 0) return n;
    for (int i = 0; i < n; ++i) {
      const trigger::TriggerEdge& e = edges_[static_cast<std::size_t>(i)];
      const trigger::EdgeVerdict v = pairer_->push_edge(e.t_mono_ns);
      ++edges_read_;
      if (triggered_only_ && v != trigger::EdgeVerdict::kExtra) {
        if (unclaimed_count_ == unclaimed_.size()) {  // full: the oldest is lost anyway
          std::copy(unclaimed_.begin() + 1, unclaimed_.end(), unclaimed_.begin());
          --unclaimed_count_;
        }
        unclaimed_[unclaimed_count_++] = e.t_mono_ns;
      }
      edge_log_.write(e, v, pairer_->anchor_sequence());
    }
    timeout_ms = 0;  // only the first read may wait
    if (n < static_cast<int>(edges_.size())) return 0;
  }
}

void TriggerPairing::lead(Trigger& trigger, time::MonotonicNs t_frame_ns,
                          std::uint32_t first_sequence) {
  if (!pairer_) {
    start(first_sequence);
    trigger.set_origin(t_frame_ns - config_.latency_ns);
  }
  trigger.advance_to(t_frame_ns - config_.latency_ns + config_.match_tolerance_ns);
}

bool TriggerPairing::edge_in_window(time::MonotonicNs t_frame_ns, bool consume) {
  // The pairer's window (frame_pairer.hpp): edges older than it can never be claimed (dropped
  // here too); every edge inside it is consumed by the frame that pairs (when `consume`).
  const trigger::PairerConfig& pc = pairer_->config();
  const time::MonotonicNs expected = t_frame_ns - pc.latency_ns;
  const time::MonotonicNs lo = expected - pc.match_tolerance_ns;
  const time::MonotonicNs hi = expected + pc.match_tolerance_ns;
  std::size_t old = 0;
  while (old < unclaimed_count_ && unclaimed_[old] < lo)
    ++old;
  std::size_t in_window = old;
  while (in_window < unclaimed_count_ && unclaimed_[in_window] <= hi)
    ++in_window;
  const bool found = in_window > old;
  const std::size_t consumed = found && consume ? in_window : old;
  std::copy(unclaimed_.begin() + static_cast<std::ptrdiff_t>(consumed),
            unclaimed_.begin() + static_cast<std::ptrdiff_t>(unclaimed_count_), unclaimed_.begin());
  unclaimed_count_ -= consumed;
  return found;
}

void TriggerPairing::change_rate(double rate_hz) {
  const auto period = static_cast<std::int64_t>(std::llround(1e9 / rate_hz));
  config_.period_ns = period;
  config_.match_tolerance_ns = period / 4;
  config_.edge_phase_tolerance_ns = period / 4;
  // Before: it restarted at the first sequence.
  if (pairer_)
    start(pairer_->counters().edges_seen > 0 ? pairer_->anchor_sequence() + 1
                                             : config_.first_sequence);
}

void TriggerPairing::add_stats(nlohmann::json& stats) const {
  if (!pairer_) return;
  const trigger::PairerCounters& pc = pairer_->counters();
  stats["pairing"] = {
      {"edges_seen", pc.edges_seen},       {"edges_extra", pc.edges_extra},
      {"edges_missing", pc.edges_missing}, {"edges_unmatched", pc.edges_unmatched},
      {"frames_paired", pc.frames_paired}, {"frames_unmatched", pc.frames_unmatched},
      {"ambiguous", pc.ambiguous},         {"resyncs", pc.resyncs},
      {"period_ns", config_.period_ns}};
}

}  // namespace storetrack::unit
