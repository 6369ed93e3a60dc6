// TriggerPairing: the trigger edges read into the pairer, which gives each frame its trigger
// sequence number and exposure start (storetrack/trigger/frame_pairer.hpp), and the
// triggered-only window: the edges no frame has claimed yet.
//
// trigger.triggered_only: a frame with no unclaimed edge in its window never reaches the pairer;
// an unmatched frame would take (and so advance) a sequence number the next triggered frame
// needs. Fixed storage: nothing here allocates after configure().
#pragma once

#include <array>
#include <cstdint>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>

#include "input/trigger.hpp"
#include "pairing/edge_log.hpp"
#include "storetrack/trigger/frame_pairer.hpp"
#include "storetrack/trigger/trigger_line.hpp"
#include "unit_config.hpp"

namespace storetrack::unit {

class TriggerPairing {
 public:
  /// The pairer's configuration from the trigger's; refused (`error`) when inconsistent.
  bool configure(const TriggerConfig& config, std::string& error);
  /// Starts the numbering at `first_sequence` (again, after a rate change).
  void start(std::uint32_t first_sequence);
  bool started() const { return pairer_.has_value(); }
  EdgeLog& edge_log() { return edge_log_; }

  /// Reads every pending edge of `trigger` into the pairer. A failed read is counted
  /// (read_errors()) and retried once at once (a transient error: the edges are still queued,
  /// and a frame paired without its own edge would be flagged trigger-missing); a second
  /// failure in a row is returned. 0 when not started.
  int drain(Trigger& trigger, int timeout_ms);
  /// A trigger that follows the frames (sim) is started by the first frame, phased on it, and
  /// moved on by each to the end of the frame's pairing window.
  void lead(Trigger& trigger, time::MonotonicNs t_frame_ns, std::uint32_t first_sequence);
  /// triggered_only: whether an unclaimed edge lies in the frame's pairing window; edges older
  /// than the window are dropped, and with `consume` the edges in it are claimed.
  bool edge_in_window(time::MonotonicNs t_frame_ns, bool consume);
  void pair(time::MonotonicNs t_frame_ns, trigger::PairResult& out) {
    pairer_->pair_frame(t_frame_ns, out);
  }
  /// A new trigger rate: the numbering goes on from the last edge, so a rate change never
  /// renumbers this unit's exposures against the others'.
  void change_rate(double rate_hz);

  const trigger::PairerCounters& counters() const { return pairer_->counters(); }
  std::uint64_t edges_read() const { return edges_read_; }
  std::uint64_t read_errors() const { return read_errors_; }
  /// The "pairing" block of the stats (when started).
  void add_stats(nlohmann::json& stats) const;

 private:
  trigger::PairerConfig config_;
  std::optional<trigger::TriggerFramePairer> pairer_;
  bool triggered_only_ = false;
  std::array<trigger::TriggerEdge, 64> edges_{};
  // Times of accepted edges no frame has claimed yet, oldest first (triggered_only).
  std::array<time::MonotonicNs, trigger::TriggerFramePairer::kCapacity> unclaimed_{};
  std::size_t unclaimed_count_ = 0;
  std::uint64_t edges_read_ = 0;
  std::uint64_t read_errors_ = 0;
  EdgeLog edge_log_;
};

}  // namespace storetrack::unit
