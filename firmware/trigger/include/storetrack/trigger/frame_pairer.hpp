// TriggerFramePairer: gives every frame the trigger edge that exposed it, by time.
//
// Pure logic (no I/O, no allocation, no exceptions). Two steps:
//  1. push_edge(): each edge gets a trigger sequence number from its phase on the nominal
//     trigger period, anchored on the last accepted edge: seq = seq_anchor + round(dt / period).
//     An edge that is not within edge_phase_tolerance_ns of a period boundary after the anchor
//     (double pulse, glitch) is EXTRA and not used; a gap of n periods means n - 1 MISSING
//     edges. Numbering by phase rather than by counting keeps the sequence shared with the other
//     units that saw the same trigger even when this unit misses or doubles an edge.
//  2. pair_frame(): a frame time stamped t_frame was triggered by an edge near
//     t_frame - latency_ns; an edge inside +-match_tolerance_ns of that is paired. Edges older
//     than the window never got a frame (counted); a frame with no edge in its window is
//     flagged trigger-missing and its sequence is inferred from the edge phase (counted).
//     If two edges fall in one window the one nearest the expected time wins and the case is
//     counted as ambiguous: nothing is paired silently.
// The caller must push every edge with t <= t_frame - latency_ns + match_tolerance_ns before
// pairing that frame (drain the trigger line first; its events precede the frame's DQBUF).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>

#include "storetrack/time/time.hpp"

namespace storetrack::trigger {

struct PairerConfig {
  std::int64_t period_ns = 10'000'000;          ///< nominal trigger period (> 0)
  std::int64_t latency_ns = 0;                  ///< expected (frame time stamp - edge time)
  std::int64_t match_tolerance_ns = 1'000'000;  ///< half-width of the frame->edge window
  /// How far (either side) an edge may be from the anchor's period grid and still be a real
  /// trigger; further off it is an extra edge. Must be < period / 2.
  std::int64_t edge_phase_tolerance_ns = 2'500'000;
  /// Exposure start relative to the trigger edge (camera trigger delay).
  std::int64_t trigger_to_exposure_ns = 0;
  /// After this many consecutive off-phase edges the trigger is assumed to have changed phase
  /// or rate and the numbering re-anchors on the newest edge (counted as a resync).
  int resync_after_off_phase = 3;
  std::uint32_t first_sequence = 0;  ///< sequence number of the first edge
};

/// Checks a configuration; returns 0 or -EINVAL (message in *why when given).
int validate(const PairerConfig& config, const char** why = nullptr);

struct PairerCounters {
  std::uint64_t edges_seen = 0;        ///< every edge pushed
  std::uint64_t edges_extra = 0;       ///< off-phase edges (double pulses, glitches), not used
  std::uint64_t edges_missing = 0;     ///< period slots with no edge (gaps in the edge train)
  std::uint64_t edges_unmatched = 0;   ///< accepted edges that no frame claimed
  std::uint64_t frames_paired = 0;     ///< frames paired with an edge
  std::uint64_t frames_unmatched = 0;  ///< frames with no edge in their window
  std::uint64_t ambiguous = 0;         ///< windows that held more than one edge
  std::uint64_t resyncs = 0;           ///< re-anchorings of the sequence numbering
};

enum class EdgeVerdict : std::uint8_t { kAccepted, kExtra, kResync };

struct PairResult {
  bool matched = false;                ///< false: no edge; sequence and times are inferred
  std::uint32_t trigger_seq = 0;       ///< sequence of the exposure
  time::MonotonicNs edge_mono_ns = 0;  ///< the edge (or the inferred edge time)
  time::MonotonicNs exposure_start_mono_ns = 0;  ///< edge + trigger_to_exposure_ns
  std::int64_t latency_error_ns = 0;             ///< (t_frame - edge) - latency_ns, when matched
  bool sequence_known = false;  ///< false only before any edge or frame reference exists
};

class TriggerFramePairer {
 public:
  static constexpr std::size_t kCapacity = 64;  ///< pending edges kept (160 ms at 400 Hz)

  /// config must pass validate().
  explicit TriggerFramePairer(const PairerConfig& config);

  EdgeVerdict push_edge(time::MonotonicNs t_edge_ns);
  void pair_frame(time::MonotonicNs t_frame_ns, PairResult& out);
  /// Edges still waiting for a frame.
  std::size_t pending() const { return count_; }
  /// Sequence number of the last accepted edge.
  std::uint32_t anchor_sequence() const { return anchor_seq_; }
  const PairerCounters& counters() const { return counters_; }
  const PairerConfig& config() const { return config_; }

 private:
  struct PendingEdge {
    time::MonotonicNs t_ns;
    std::uint32_t seq;
  };
  void drop_front();
  std::int64_t periods_between(time::MonotonicNs from, time::MonotonicNs to) const;

  PairerConfig config_;
  PairerCounters counters_;
  std::array<PendingEdge, kCapacity> ring_{};
  std::size_t head_ = 0;
  std::size_t count_ = 0;
  bool have_anchor_ = false;
  time::MonotonicNs anchor_t_ns_ = 0;
  std::uint32_t anchor_seq_ = 0;
  int off_phase_run_ = 0;
  bool have_last_frame_ = false;
  time::MonotonicNs last_frame_edge_ns_ = 0;  ///< edge time (actual or inferred) of last frame
  std::uint32_t last_frame_seq_ = 0;
};

}  // namespace storetrack::trigger
