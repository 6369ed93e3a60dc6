#include "storetrack/trigger/sim_trigger.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>

namespace storetrack::trigger {

SimTriggerLine::SimTriggerLine(const SimTriggerConfig& config)
    : config_(config), rng_(config.seed) {}

void SimTriggerLine::enqueue(time::MonotonicNs t, std::uint32_t count) {
  ++stats_.edges;
  if (count_ == queue_.size()) {  // reader fell behind: lose the oldest, as a kernel queue does
    head_ = (head_ + 1) % queue_.size();
    --count_;
    ++stats_.dropped_edges;
  }
  queue_[(head_ + count_) % queue_.size()] = TriggerEdge{t, count};
  ++count_;
}

void SimTriggerLine::advance_to(time::MonotonicNs t_ns) {
  origin_set_ = true;
  while (t0_ns_ + static_cast<std::int64_t>(next_k_) * config_.period_ns <= t_ns) {
    const std::uint64_t k = next_k_++;
    const double jitter =
        config_.jitter_ns > 0 ? jitter_(rng_) * static_cast<double>(config_.jitter_ns) : 0.0;
    const time::MonotonicNs t = t0_ns_ + static_cast<std::int64_t>(k) * config_.period_ns +
                                static_cast<std::int64_t>(std::llround(jitter));
    const bool dropped =
        config_.drop_every > 0 && k % static_cast<std::uint64_t>(config_.drop_every) ==
                                      static_cast<std::uint64_t>(config_.drop_every - 1);
    if (!dropped) enqueue(t, line_count_++);
    const bool extra =
        config_.extra_every > 0 && k % static_cast<std::uint64_t>(config_.extra_every) ==
                                       static_cast<std::uint64_t>(config_.extra_every - 1);
    if (extra) {
      const std::int64_t offset =
          config_.extra_offset_ns > 0 ? config_.extra_offset_ns : config_.period_ns / 2;
      enqueue(t + offset, line_count_++);
    }
  }
}

int SimTriggerLine::read_edges(std::span<TriggerEdge> out, int /*timeout_ms*/) {
  if (config_.read_error_every > 0 &&
      ++reads_ % static_cast<std::uint64_t>(config_.read_error_every) == 0) {
    ++stats_.line_errors;
    return -EIO;  // the queue stays: the next read gets these edges
  }
  const std::size_t n = std::min(out.size(), count_);
  for (std::size_t i = 0; i < n; ++i) {
    out[i] = queue_[head_];
    head_ = (head_ + 1) % queue_.size();
    --count_;
  }
  return static_cast<int>(n);
}

}  // namespace storetrack::trigger
