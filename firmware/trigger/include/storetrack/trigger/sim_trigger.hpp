// SimTriggerLine: a trigger line on a simulated time axis, for running the unit without GPIO
// (simulator and replay sources) and for tests of everything downstream of the trigger.
//
// Edges fall at t0 + k * period + jitter. advance_to(t) releases every edge up to time t; the
// capture loop calls it with each frame's expected edge time, so simulated frames and edges
// live on the same (simulated) clock. Faults can be injected: every Nth edge missing, an extra
// edge after every Mth edge, every Kth read failing (as a GPIO event read can).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <random>

#include "storetrack/trigger/trigger_line.hpp"

namespace storetrack::trigger {

struct SimTriggerConfig {
  std::int64_t period_ns = 10'000'000;
  std::int64_t jitter_ns = 0;        ///< standard deviation of Gaussian edge jitter
  int drop_every = 0;                ///< 0: none; else edge k is missing when k % N == N-1
  int extra_every = 0;               ///< 0: none; else an extra edge after k % M == M-1
  std::int64_t extra_offset_ns = 0;  ///< extra edge delay after its edge (0: period / 2)
  int read_error_every = 0;  ///< 0: none; else every Nth read_edges() fails with -EIO (edges kept)
  std::uint64_t seed = 1;
};

class SimTriggerLine final : public TriggerLine {
 public:
  explicit SimTriggerLine(const SimTriggerConfig& config);

  /// Sets the time of edge 0 (default: 0). Call before the first advance_to().
  void set_origin(time::MonotonicNs t0_ns) { t0_ns_ = t0_ns; }
  /// Releases all edges with nominal time <= t_ns into the read queue.
  void advance_to(time::MonotonicNs t_ns);
  bool has_origin() const { return origin_set_; }
  void mark_origin_set() { origin_set_ = true; }

  int start() override { return 0; }
  int stop() override { return 0; }
  int read_edges(std::span<TriggerEdge> out, int timeout_ms) override;
  bool is_master() const override { return true; }
  TriggerLineStats stats() const override { return stats_; }
  const char* name() const override { return "sim trigger"; }

  /// Edges generated so far (truth for tests), not counting injected extras.
  std::uint64_t nominal_edges() const { return next_k_; }

 private:
  void enqueue(time::MonotonicNs t, std::uint32_t count);

  SimTriggerConfig config_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> jitter_{0.0, 1.0};
  time::MonotonicNs t0_ns_ = 0;
  bool origin_set_ = false;
  std::uint64_t next_k_ = 0;
  std::uint32_t line_count_ = 0;
  std::array<TriggerEdge, 256> queue_{};
  std::size_t head_ = 0;
  std::size_t count_ = 0;
  std::uint64_t reads_ = 0;
  TriggerLineStats stats_;
};

}  // namespace storetrack::trigger
