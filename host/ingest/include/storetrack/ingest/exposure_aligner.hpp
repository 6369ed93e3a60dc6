// ExposureAligner: groups the MarkObservations of one exposure (same trigger sequence) across
// cameras, releasing each exposure when every rig camera has delivered it or when its bounded
// wait expires, so one dead camera never stalls the output. Tolerates loss, duplicates,
// reordering, sequence wrap and restarts and unit clock jumps; every dropped observation is
// counted with its reason. Pure logic: the caller supplies the host's monotonic time, so tests
// inject faults deterministically (tests/host/ingest).
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <vector>

#include "storetrack/msg/messages.hpp"
#include "storetrack/pipeline/aligned_exposure.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::ingest {

struct AlignerConfig {
  /// Camera ids in rig order (rig.cameras[i].id): bit i of missing_camera_mask is camera_ids[i].
  std::vector<int> camera_ids;
  /// Longest wait for the missing cameras of an exposure, from its first observation's arrival
  /// (host CLOCK_MONOTONIC). Bounds the latency added by a dead camera.
  time::MonotonicNs max_wait_ns = 10'000'000;
  /// Observations with the same trigger sequence whose exposure mid-points (TAI) differ by more
  /// than this are inconsistent (a unit's clock jumped, or a sequence number was reused): the
  /// later one is dropped.
  std::int64_t max_mid_time_spread_ns = 2'000'000;
  /// Exposures waiting at once; beyond it the oldest is released early (counted).
  std::size_t max_pending = 64;
  /// Exposures with fewer delivered cameras are dropped (counted), not released.
  int min_cameras = 1;
  /// A sequence this far BEHIND the newest released one means the trigger source restarted.
  std::uint32_t sequence_restart_threshold = 1000;
};

/// Why observations or exposures were dropped, and what was released. All counts since start.
struct AlignerCounters {
  std::uint64_t observations_in = 0;
  std::uint64_t observations_used = 0;
  std::uint64_t exposures_complete = 0;          ///< released with every camera
  std::uint64_t exposures_partial_timeout = 0;   ///< released on the deadline, cameras missing
  std::uint64_t exposures_partial_overflow = 0;  ///< released early: too many pending
  std::uint64_t exposures_dropped_too_few_cameras = 0;
  std::uint64_t dropped_unknown_camera = 0;  ///< camera_id not in the rig
  std::uint64_t dropped_invalid = 0;         ///< invalid sequence or time fields
  std::uint64_t dropped_duplicate = 0;       ///< same camera, same exposure, seen before
  std::uint64_t dropped_late = 0;            ///< exposure already released without it
  std::uint64_t dropped_time_mismatch = 0;   ///< mid-time disagrees with the other cameras
  std::uint64_t sequence_restarts = 0;
  std::uint64_t camera_missing_total = 0;  ///< sum over released exposures of missing cameras
};

struct CameraCounters {
  std::uint64_t received = 0;
  std::uint64_t used = 0;
  std::uint64_t missing = 0;  ///< released exposures without this camera
  std::uint64_t time_mismatch = 0;
  std::uint64_t late = 0;
  std::uint64_t duplicate = 0;
};

class ExposureAligner {
 public:
  explicit ExposureAligner(AlignerConfig config);

  /// Adds one observation received at host time `now`; appends released exposures to `out`.
  void push(const msg::MarkObservations& obs, time::MonotonicNs now,
            std::vector<pipeline::AlignedExposure>& out);
  /// Releases exposures whose wait expired by `now`.
  void poll(time::MonotonicNs now, std::vector<pipeline::AlignedExposure>& out);
  /// Releases everything pending (end of input).
  void flush(std::vector<pipeline::AlignedExposure>& out);
  /// Host time at which the oldest pending exposure times out; INT64_MAX when none pending.
  time::MonotonicNs next_deadline() const;

  std::size_t pending() const { return pending_.size(); }
  const AlignerCounters& counters() const { return counters_; }
  const std::vector<CameraCounters>& camera_counters() const { return camera_counters_; }
  const AlignerConfig& config() const { return config_; }

 private:
  struct Pending {
    std::vector<msg::MarkObservations> cameras;
    std::uint32_t present_mask = 0;
    time::MonotonicNs first_arrival = 0;
    time::TaiNs reference_mid_tai_ns = 0;
  };
  enum class ReleaseReason { kComplete, kTimeout, kOverflow, kFlush };

  int camera_index(int camera_id) const;
  std::int64_t unwrap(std::uint32_t seq) const;
  void release(std::map<std::int64_t, Pending>::iterator it, ReleaseReason reason,
               std::vector<pipeline::AlignedExposure>& out);
  void release_ready(time::MonotonicNs now, std::vector<pipeline::AlignedExposure>& out);
  void remember_released(std::int64_t key, std::uint32_t mask);

  AlignerConfig config_;
  std::uint32_t all_mask_ = 0;
  std::map<std::int64_t, Pending> pending_;  // by unwrapped trigger sequence
  bool have_reference_ = false;
  std::int64_t newest_seen_ = 0;       // unwrapped sequence used as the unwrap reference
  std::int64_t released_through_ = 0;  // every exposure <= this has been released
  bool released_any_ = false;
  static constexpr std::size_t kHistory = 1024;
  std::array<std::int64_t, kHistory> history_key_{};
  std::array<std::uint32_t, kHistory> history_mask_{};
  AlignerCounters counters_;
  std::vector<CameraCounters> camera_counters_;
};

}  // namespace storetrack::ingest
