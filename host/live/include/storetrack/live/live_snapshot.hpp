// The live view's snapshot (docs/live-view.md): what the real-time thread of storetrack-host
// hands to the live page's server. Fixed capacity (no allocation after construction), published
// through a triple buffer: the writer never waits on the reader, the reader always gets the
// latest complete snapshot and never a torn one.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <vector>

#include "storetrack/geometry/transform.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/pipeline/aligned_exposure.hpp"
#include "storetrack/pipeline/exposure_result.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::live {

/// The aligner's limit on rig cameras (ExposureAligner: at most 32); units at most one per camera.
inline constexpr int kMaxLiveCameras = 32;
inline constexpr int kMaxLiveUnits = kMaxLiveCameras;
inline constexpr int kMaxLiveMarks = static_cast<int>(msg::kMaxMarks);

/// One observation of one camera as the host used it.
struct LiveMark {
  float x_px = 0, y_px = 0;
  /// Observed minus reprojected [px] of the triangulated mark; meaningful with has_residual.
  float residual_x_px = 0, residual_y_px = 0;
  std::int16_t id = -1;  ///< -1: not identified
  char body = '?';       ///< 'p' pylon, 's' store, '?' other or not identified
  bool has_residual = false;
  bool excluded = false;  ///< removed by the rigid-body test
};

struct LiveCamera {
  int camera_id = 0, unit_id = 0;  ///< from the rig calibration
  bool delivered = false;          ///< this camera is in the snapshot's exposure
  // The camera's observation message (valid when delivered).
  std::uint32_t trigger_seq = 0;
  std::int64_t exposure_start_tai_ns = 0;
  std::uint32_t exposure_duration_ns = 0;
  std::uint8_t clock_state = 0xFF;
  std::uint16_t flags = 0;
  int mark_count = 0;  ///< marks the unit sent (all of them are in `marks`)
  std::array<LiveMark, kMaxLiveMarks> marks{};
  ingest::CameraCounters counters;  ///< the aligner's, at publication
  /// The camera's newest observation in any processed exposure (this one or an earlier one):
  /// its health when this exposure lacks it. last_seen_mono_ns 0: never seen.
  std::uint8_t last_clock_state = 0xFF;
  time::MonotonicNs last_seen_mono_ns = 0;
};

struct LiveUnit {
  int unit_id = 0;
  bool heard = false;  ///< a UnitHealth message arrived
  msg::UnitHealth health{};
  time::MonotonicNs heard_mono_ns = 0;
  std::uint64_t messages = 0;
};

struct LiveBodyPose {
  bool valid = false;
  std::uint32_t trigger_seq = 0;  ///< exposure it was solved in (the last valid one)
  geometry::Transform T_w_b = geometry::Transform::Identity();
};

/// The host's loop totals the page shows (hostapp LoopTotals, less what it does not need).
struct LiveTotals {
  std::uint64_t exposures = 0, samples_written = 0, valid_samples = 0, samples_withheld = 0,
                health_messages = 0;
};

struct LiveSnapshot {
  std::uint64_t publication = 0;  ///< 1, 2, ...: counts publications
  time::MonotonicNs published_mono_ns = 0;
  // The newest processed exposure (written as a sample or withheld).
  std::uint32_t trigger_seq = 0;
  time::TaiNs exposure_mid_tai_ns = 0;
  std::uint32_t missing_camera_mask = 0;
  bool closed_by_timeout = false;
  int cameras_used = 0;
  bool sample_written = false;  ///< this exposure became a sample
  int camera_count = 0;         ///< rig cameras, in rig order
  std::array<LiveCamera, kMaxLiveCameras> cameras{};
  int unit_count = 0;
  std::array<LiveUnit, kMaxLiveUnits> units{};
  ingest::AlignerCounters aligner;
  LiveTotals totals;
  /// The newest WRITTEN sample (as sent on iNET-X); has_sample false before the first.
  bool has_sample = false;
  msg::FtiSample sample{};
  LiveBodyPose pylon, store;  ///< last valid T_w_p, T_w_s (the page projects the surveys)
};

/// Single writer, single reader, wait-free on both sides: three buffers, one the writer fills,
/// one the reader holds, one in the middle, swapped with one atomic exchange each.
template <class T>
class TripleBuffer {
 public:
  TripleBuffer() : buffers_(std::make_unique<std::array<T, 3>>()) {}

  /// The writer's buffer: fill it completely (it holds an older snapshot), then publish().
  T& back() { return (*buffers_)[back_]; }
  void publish() { back_ = middle_.exchange(back_ | kFresh, std::memory_order_acq_rel) & kIndex; }

  /// Reader: takes the newest published buffer when there is one since the last take; front()
  /// stays valid (the writer never touches it) until the next take.
  bool take() {
    if ((middle_.load(std::memory_order_relaxed) & kFresh) == 0) return false;
    front_ = middle_.exchange(front_, std::memory_order_acq_rel) & kIndex;
    return true;
  }
  const T& front() const { return (*buffers_)[front_]; }

 private:
  static constexpr std::uint8_t kIndex = 3, kFresh = 4;
  static_assert(std::atomic<std::uint8_t>::is_always_lock_free);
  std::unique_ptr<std::array<T, 3>> buffers_;
  std::uint8_t back_ = 0, front_ = 2;  // each owned by one side
  std::atomic<std::uint8_t> middle_{1};
};

/// Camera and unit ids of the rig, in rig order (rig.cameras).
struct LiveRig {
  std::vector<int> camera_ids, unit_ids;
};

/// The real-time thread's side: copies what the page shows into the triple buffer's back
/// snapshot at most once per `min_interval_ns` (the page needs >= 10 Hz; the default 20 ms
/// keeps the copy off most exposures at 400 fps). Never allocates, locks or waits after
/// construction; the server thread reads with take()/front().
class LivePublisher {
 public:
  /// Throws std::invalid_argument for more than kMaxLiveCameras cameras or mismatched lists.
  explicit LivePublisher(const LiveRig& rig, time::MonotonicNs min_interval_ns = 20'000'000);

  /// A processed exposure; publishes when the interval since the last publication passed.
  /// Returns true when it published.
  bool on_exposure(const pipeline::AlignedExposure& exposure,
                   const pipeline::ExposureResult& result, bool sample_written,
                   const ingest::ExposureAligner& aligner, const LiveTotals& totals,
                   time::MonotonicNs now);
  /// A UnitHealth message: kept for the next publication (a unit not in the rig is counted).
  void on_health(const msg::UnitHealth& health, time::MonotonicNs now);

  // Reader side (one thread): see TripleBuffer.
  bool take() { return buffer_.take(); }
  const LiveSnapshot& front() const { return buffer_.front(); }

  std::uint64_t publications() const { return publications_; }
  std::uint64_t health_from_unknown_unit() const { return health_unknown_unit_; }

 private:
  void fill(LiveSnapshot& s, const pipeline::AlignedExposure& exposure,
            const pipeline::ExposureResult& result, bool sample_written,
            const ingest::ExposureAligner& aligner, const LiveTotals& totals,
            time::MonotonicNs now) const;

  LiveRig rig_;
  time::MonotonicNs min_interval_ns_;
  time::MonotonicNs last_publication_ns_ = 0;
  std::uint64_t publications_ = 0, health_unknown_unit_ = 0;
  // Writer-side state carried between publications.
  std::array<LiveUnit, kMaxLiveUnits> units_{};
  int unit_count_ = 0;
  bool has_sample_ = false;
  msg::FtiSample sample_{};
  LiveBodyPose pylon_, store_;
  struct LastSeen {
    std::uint8_t clock_state = 0xFF;
    time::MonotonicNs mono_ns = 0;
  };
  std::array<LastSeen, kMaxLiveCameras> last_seen_{};  // rig order
  TripleBuffer<LiveSnapshot> buffer_;
};

}  // namespace storetrack::live
