// Predicted-window tracking: centroid only small windows around where each mark will be.
//
// After a full-frame pass every mark found becomes a track. For the next frame each track's
// position is extrapolated from its last one, two or three centroids (Lagrange through the
// points in time: constant position, velocity or acceleration), and its window's half-size is
//   n_sigma * sigma_c * sqrt(sum L_i^2)        centroid noise carried through the extrapolation
// + bound / k! * |prod (t - t_i)|              the next derivative's bound (speed, acceleration
//                                               or jerk), the Lagrange remainder
// + the mark's thresholded radius + margin_px  so the refinement patch fits inside.
// The existing centroider then searches only those windows (its ROI mode: same background,
// threshold, components and refinement as a full frame, so the centroids are the same).
//
// A full frame is taken instead when nothing is tracked, every full_frame_interval frames, on
// request, after a time gap, when a window would touch another mark (reach the square where
// that mark's pixels can be: its prediction +- its reach_px; the windows' margins may overlap,
// the marks may not, so no mark is seen by two windows), or when the last full frame found
// more marks than there are windows. A window that finds no mark or cuts its mark (the mark
// was lost: hidden, left the window or the prediction failed) sends the SAME frame through a
// full pass at once (recover_in_same_frame), so no mark the full pass would find is missed;
// without it the next frame is a full one. New marks are found by the periodic full frames.
//
// The per-frame path allocates nothing and throws nothing: tracks live in fixed arrays; bad
// input is a negative return value and a counter.
#pragma once

#include <array>
#include <cstdint>
#include <span>

#include "storetrack/centroid/centroider.hpp"
#include "storetrack/frame/frame_source.hpp"

namespace storetrack::track {

/// Why a frame was centroided in full (counters are indexed by it).
enum class FullFrameCause : std::uint8_t {
  kNoTracks = 0,         ///< nothing tracked yet (start, or after an error)
  kPeriodic = 1,         ///< full_frame_interval frames since the last full one
  kRequested = 2,        ///< request_full_frame() (the host's request)
  kMarkLost = 3,         ///< a window found no mark or cut it
  kNewMarkInWindow = 4,  ///< a window held a second mark (one not tracked, or crossing)
  kWindowsTouch = 5,     ///< a window would reach another mark's pixels
  kWideWindow = 6,       ///< a prediction too uncertain for a window of max_half_px
  kTimeGap = 7,          ///< time not increasing, or more than max_gap_s since the last frame
  kTooManyMarks = 8,     ///< the last full frame found more marks than kMaxTracks
};
inline constexpr int kFullFrameCauses = 9;

struct WindowTrackerConfig {
  int full_frame_interval = 40;       ///< a full frame at least every N frames (finds new marks)
  bool recover_in_same_frame = true;  ///< a lost mark: full pass over the same frame at once
  /// Prediction bounds in the image [px/s, px/s^2, px/s^3]: the largest speed (one centroid
  /// known), acceleration (two) and jerk (three) a mark may have. Defaults: about twice what
  /// the store-separation scenario's truth shows at 400 fps (2.5e3 px/s late in the run,
  /// 5.4e4 px/s^2 and 1.3e7 px/s^3 as finite differences, both at the ejector's stroke; the
  /// pod's vibration adds ~1e4 px/s^2 at 71 Hz).
  double max_speed_px_s = 5000;
  double max_accel_px_s2 = 1e5;
  double max_jerk_px_s3 = 3e7;
  double n_sigma = 5;       ///< centroid-noise term of the window, in sigmas
  double margin_px = 4;     ///< beyond the mark's thresholded radius (refinement patch)
  int max_half_px = 48;     ///< larger windows: the mark is lost, a full frame is taken
  double max_gap_s = 0.02;  ///< longer gaps between frames: full frame
  /// Full-frame and window blobs are the same mark when within this many window half-sizes of
  /// the prediction (association after a full frame).
  double gate_halves = 1.0;
};

struct WindowTrackerStats {
  std::uint64_t frames = 0;
  std::uint64_t full_frames = 0;  ///< full passes (a same-frame recovery counts here too)
  std::uint64_t windowed_frames = 0;
  std::array<std::uint64_t, kFullFrameCauses> full_frames_by_cause{};
  std::uint64_t windows_tried = 0;
  std::uint64_t marks_lost = 0;          ///< windows that found no mark or cut it
  std::uint64_t tracks_started = 0;      ///< full-frame blobs not matching a track
  std::uint64_t tracks_dropped = 0;      ///< tracks whose mark a full frame did not find
  std::uint64_t tracks_not_started = 0;  ///< full-frame blobs beyond kMaxTracks
  std::uint64_t frames_refused = 0;      ///< centroider errors (bad frame, run overflow)
  int last_windows = 0;
  bool last_full_frame = false;
  FullFrameCause last_cause = FullFrameCause::kNoTracks;
};

/// One track's prediction for a frame and its square window of (2 half_px + 1)^2 pixels
/// centred on the pixel nearest the prediction.
struct Window {
  double predicted_x_px = 0, predicted_y_px = 0;
  double uncertainty_px = 0;  ///< bound on the prediction's error: noise and remainder terms
  double reach_px = 0;        ///< uncertainty + the mark's radius + 1: where its pixels can be
  int half_px = 0;
  std::uint32_t track_id = 0;
};

class WindowTracker {
 public:
  static constexpr int kMaxTracks = 64;

  /// Throws std::invalid_argument on an inconsistent configuration (not per frame). The
  /// centroider is its own, with max_rois raised to kMaxTracks.
  WindowTracker(const WindowTrackerConfig& config, const centroid::CentroidConfig& centroid_config,
                int max_width, int max_height);

  /// Centroids one frame exposed at time_ns (any monotonic clock). Returns the number of blobs
  /// written to `out` (raster order after a full pass, track order after a windowed one) or
  /// the centroider's negative error (counted; the tracks are dropped). If `track_ids` is not
  /// empty it receives each blob's track id (same index as `out`). Never allocates or throws.
  int process(const frame::FrameView& frame, std::int64_t time_ns, std::span<centroid::Blob> out,
              std::span<std::uint32_t> track_ids = {});

  /// The next frame is centroided in full.
  void request_full_frame() { full_frame_requested_ = true; }
  /// Forgets every track and the last frame's time (a restarted stream); counters stay.
  void reset();

  /// Windows of the last windowed pass (empty after a full one).
  std::span<const Window> last_windows() const {
    return {windows_.data(), static_cast<std::size_t>(stats_.last_windows)};
  }
  int track_count() const { return track_count_; }
  const WindowTrackerStats& stats() const { return stats_; }
  const centroid::Centroider& centroider() const { return centroider_; }

 private:
  struct Track {
    std::array<std::int64_t, 3> t_ns{};  // newest first
    std::array<double, 3> x{}, y{}, sigma{};
    int points = 0;
    float radius_px = 0;  // thresholded radius of the last blob
    std::uint32_t id = 0;
  };
  static constexpr int kWindowBlobs = 2 * kMaxTracks;

  bool choose_full_frame(std::int64_t time_ns, FullFrameCause& cause);
  void predict(const Track& track, std::int64_t time_ns, Window& window) const;
  int full_pass(const frame::FrameView& frame, std::int64_t time_ns, FullFrameCause cause,
                std::span<centroid::Blob> out, std::span<std::uint32_t> track_ids);
  int windowed_pass(const frame::FrameView& frame, std::int64_t time_ns,
                    std::span<centroid::Blob> out, std::span<std::uint32_t> track_ids,
                    FullFrameCause& failure);
  int refuse(int rc);
  static void add_point(Track& track, std::int64_t time_ns, const centroid::Blob& blob);
  bool window_cuts_blob(const centroid::Roi& roi, const centroid::Blob& blob) const;

  WindowTrackerConfig config_;
  centroid::Centroider centroider_;
  int frame_width_ = 0, frame_height_ = 0;
  std::array<Track, kMaxTracks> tracks_{};
  std::array<Track, kMaxTracks> next_tracks_{};
  int track_count_ = 0;
  std::array<Window, kMaxTracks> windows_{};  // per track: this frame's prediction
  std::array<centroid::Roi, kMaxTracks> rois_{};
  std::array<int, kMaxTracks> blob_of_track_{};  // window or full-frame blob index, -1: none
  std::array<centroid::Blob, kWindowBlobs> window_blobs_{};
  std::int64_t last_time_ns_ = 0;
  bool have_time_ = false;
  bool full_frame_requested_ = false;
  bool too_many_marks_ = false;
  bool have_pending_cause_ = false;  // a lost mark without same-frame recovery
  FullFrameCause pending_cause_ = FullFrameCause::kMarkLost;
  int frames_since_full_ = 0;
  std::uint32_t next_id_ = 1;
  WindowTrackerStats stats_;
};

/// Name of a cause, for logs and the benchmark's table.
const char* to_string(FullFrameCause cause);

}  // namespace storetrack::track
