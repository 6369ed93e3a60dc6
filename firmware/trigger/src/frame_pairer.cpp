#include "storetrack/trigger/frame_pairer.hpp"

#include <cerrno>
#include <cstdlib>

namespace storetrack::trigger {

int validate(const PairerConfig& c, const char** why) {
  const char* reason = nullptr;
  if (c.period_ns <= 0) {
    reason = "trigger period must be > 0";
  } else if (c.match_tolerance_ns <= 0 || 2 * c.match_tolerance_ns >= c.period_ns) {
    reason = "match tolerance must be > 0 and < period / 2 (else two edges fit one window)";
  } else if (c.edge_phase_tolerance_ns <= 0 || 2 * c.edge_phase_tolerance_ns >= c.period_ns) {
    reason = "edge phase tolerance must be > 0 and < period / 2";
  } else if (c.resync_after_off_phase < 1) {
    reason = "resync_after_off_phase must be >= 1";
  }
  if (why != nullptr) *why = reason;
  return reason == nullptr ? 0 : -EINVAL;
}

TriggerFramePairer::TriggerFramePairer(const PairerConfig& config) : config_(config) {}

std::int64_t TriggerFramePairer::periods_between(time::MonotonicNs from,
                                                 time::MonotonicNs to) const {
  // Round to nearest, symmetric for negative differences.
  const std::int64_t dt = to - from;
  const std::int64_t p = config_.period_ns;
  return dt >= 0 ? (dt + p / 2) / p : -((-dt + p / 2) / p);
}

void TriggerFramePairer::drop_front() {
  head_ = (head_ + 1) % kCapacity;
  --count_;
}

EdgeVerdict TriggerFramePairer::push_edge(time::MonotonicNs t_edge_ns) {
  ++counters_.edges_seen;
  std::uint32_t seq = config_.first_sequence;
  EdgeVerdict verdict = EdgeVerdict::kAccepted;
  if (have_anchor_) {
    const std::int64_t n = periods_between(anchor_t_ns_, t_edge_ns);
    const std::int64_t residual = (t_edge_ns - anchor_t_ns_) - n * config_.period_ns;
    const bool on_phase = n >= 1 && std::llabs(residual) <= config_.edge_phase_tolerance_ns;
    if (!on_phase) {
      ++off_phase_run_;
      if (off_phase_run_ < config_.resync_after_off_phase) {
        ++counters_.edges_extra;
        return EdgeVerdict::kExtra;
      }
      // The trigger changed phase or rate: re-anchor on this edge, never reusing a number.
      ++counters_.resyncs;
      verdict = EdgeVerdict::kResync;
      seq = anchor_seq_ + static_cast<std::uint32_t>(n >= 1 ? n : 1);
    } else {
      if (n > 1) counters_.edges_missing += static_cast<std::uint64_t>(n - 1);
      seq = anchor_seq_ + static_cast<std::uint32_t>(n);
    }
  }
  off_phase_run_ = 0;
  have_anchor_ = true;
  anchor_t_ns_ = t_edge_ns;
  anchor_seq_ = seq;
  if (count_ == kCapacity) {  // nobody paired the oldest edge for 64 periods
    drop_front();
    ++counters_.edges_unmatched;
  }
  ring_[(head_ + count_) % kCapacity] = PendingEdge{t_edge_ns, seq};
  ++count_;
  return verdict;
}

void TriggerFramePairer::pair_frame(time::MonotonicNs t_frame_ns, PairResult& out) {
  const time::MonotonicNs expected = t_frame_ns - config_.latency_ns;
  const time::MonotonicNs window_lo = expected - config_.match_tolerance_ns;
  const time::MonotonicNs window_hi = expected + config_.match_tolerance_ns;
  out = PairResult{};

  // Edges before the window will never be claimed: their exposure produced no frame.
  while (count_ > 0 && ring_[head_].t_ns < window_lo) {
    drop_front();
    ++counters_.edges_unmatched;
  }
  // Edges inside the window: take the one nearest the expected time; others are counted.
  std::size_t in_window = 0;
  PendingEdge best{};
  std::int64_t best_error = 0;
  while (count_ > 0 && ring_[head_].t_ns <= window_hi) {
    const PendingEdge e = ring_[head_];
    const std::int64_t err = e.t_ns - expected;
    if (in_window == 0 || std::llabs(err) < std::llabs(best_error)) {
      best = e;
      best_error = err;
    }
    ++in_window;
    drop_front();
  }
  if (in_window > 1) {
    ++counters_.ambiguous;
    counters_.edges_unmatched += in_window - 1;
  }

  if (in_window > 0 && (!have_last_frame_ || best.seq != last_frame_seq_)) {
    ++counters_.frames_paired;
    out.matched = true;
    out.sequence_known = true;
    out.trigger_seq = best.seq;
    out.edge_mono_ns = best.t_ns;
    out.latency_error_ns = -best_error;
  } else {
    ++counters_.frames_unmatched;
    out.matched = false;
    out.edge_mono_ns = expected;
    // Infer the sequence from the edge train's phase, else from the previous frame.
    if (have_anchor_) {
      out.sequence_known = true;
      out.trigger_seq =
          anchor_seq_ + static_cast<std::uint32_t>(periods_between(anchor_t_ns_, expected));
    } else if (have_last_frame_) {
      out.sequence_known = true;
      out.trigger_seq = last_frame_seq_ +
                        static_cast<std::uint32_t>(periods_between(last_frame_edge_ns_, expected));
    } else {
      out.sequence_known = false;
      out.trigger_seq = config_.first_sequence;
    }
    // Sequence numbers of successive frames must increase: a frame closer than half a period
    // to the previous one still gets a fresh number (it is flagged trigger-missing anyway).
    if (have_last_frame_ && static_cast<std::int32_t>(out.trigger_seq - last_frame_seq_) <= 0) {
      out.trigger_seq = last_frame_seq_ + 1;
    }
  }
  out.exposure_start_mono_ns = out.edge_mono_ns + config_.trigger_to_exposure_ns;
  have_last_frame_ = true;
  last_frame_seq_ = out.trigger_seq;
  last_frame_edge_ns_ = out.edge_mono_ns;
}

}  // namespace storetrack::trigger
