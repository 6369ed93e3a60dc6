// WindowTracker: see the header for the method.
#include "storetrack/track/window_tracker.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <stdexcept>
#include <string>

namespace storetrack::track {
namespace {

using centroid::Blob;
using centroid::Roi;

centroid::CentroidConfig with_windows(centroid::CentroidConfig config) {
  config.max_rois = std::max(config.max_rois, WindowTracker::kMaxTracks);
  return config;
}

/// True if either window reaches the other's mark: the square of +-reach_px around its
/// prediction, where that mark's thresholded pixels can be. Then a mark would be seen, or cut,
/// by two windows. The margins beyond the marks may overlap: they hold only background.
/// (ax, ay), (bx, by): the windows' centre pixels, the predictions rounded once per frame by
/// the caller (rounding in here, per pair, was 14 % of a windowed frame's instructions at 64
/// marks).
bool touch(const Window& a, long ax, long ay, const Window& b, long bx, long by) {
  const double dx = static_cast<double>(std::abs(ax - bx));
  const double dy = static_cast<double>(std::abs(ay - by));
  const double distance = std::max(dx, dy);  // the windows are squares
  return distance <= a.half_px + b.reach_px || distance <= b.half_px + a.reach_px;
}

}  // namespace

const char* to_string(FullFrameCause cause) {
  switch (cause) {
    case FullFrameCause::kNoTracks:
      return "no tracks";
    case FullFrameCause::kPeriodic:
      return "periodic";
    case FullFrameCause::kRequested:
      return "requested";
    case FullFrameCause::kMarkLost:
      return "mark lost";
    case FullFrameCause::kNewMarkInWindow:
      return "new mark in a window";
    case FullFrameCause::kWindowsTouch:
      return "windows touch";
    case FullFrameCause::kWideWindow:
      return "window too wide";
    case FullFrameCause::kTimeGap:
      return "time gap";
    case FullFrameCause::kTooManyMarks:
      return "too many marks";
  }
  return "?";
}

WindowTracker::WindowTracker(const WindowTrackerConfig& config,
                             const centroid::CentroidConfig& centroid_config, int max_width,
                             int max_height)
    : config_(config), centroider_(with_windows(centroid_config), max_width, max_height) {
  auto fail = [](const std::string& what) {
    throw std::invalid_argument("window tracker config: " + what);
  };
  if (config.full_frame_interval < 1) fail("full_frame_interval must be >= 1");
  if (!(config.max_speed_px_s > 0) || !(config.max_accel_px_s2 > 0) || !(config.max_jerk_px_s3 > 0))
    fail("max_speed_px_s, max_accel_px_s2 and max_jerk_px_s3 must be > 0");
  if (!(config.n_sigma > 0)) fail("n_sigma must be > 0");
  if (!(config.margin_px >= 0)) fail("margin_px must be >= 0");
  if (config.max_half_px < 2) fail("max_half_px must be >= 2");
  if (!(config.max_gap_s > 0)) fail("max_gap_s must be > 0");
  for (int& b : blob_of_track_)
    b = -1;
}

void WindowTracker::reset() {
  track_count_ = 0;
  have_time_ = false;
  full_frame_requested_ = false;
  too_many_marks_ = false;
  have_pending_cause_ = false;
  frames_since_full_ = 0;
}

void WindowTracker::add_point(Track& track, std::int64_t time_ns, const Blob& blob) {
  for (int i = 2; i > 0; --i) {
    track.t_ns[i] = track.t_ns[i - 1];
    track.x[i] = track.x[i - 1];
    track.y[i] = track.y[i - 1];
    track.sigma[i] = track.sigma[i - 1];
  }
  track.t_ns[0] = time_ns;
  track.x[0] = blob.x_px;
  track.y[0] = blob.y_px;
  track.sigma[0] = blob.sigma_px;
  track.points = std::min(track.points + 1, 3);
  track.radius_px = 0.5f * blob.diameter_px;
}

void WindowTracker::predict(const Track& track, std::int64_t time_ns, Window& window) const {
  // Lagrange extrapolation through the track's points to time_ns (tau = 0): the polynomial of
  // degree points - 1. Its error is f^(p)(xi) / p! * prod (t - t_i) (the interpolation
  // remainder), bounded with the configured speed, acceleration or jerk; the centroid noise
  // of the points enters as sum L_i^2 sigma_i^2.
  const int p = track.points;
  std::array<double, 3> tau{};
  for (int i = 0; i < p; ++i)
    tau[i] = 1e-9 * static_cast<double>(track.t_ns[i] - time_ns);
  double x = 0, y = 0, noise_var = 0, remainder = 1;
  for (int i = 0; i < p; ++i) {
    double basis = 1;
    for (int j = 0; j < p; ++j) {
      if (j != i) basis *= -tau[j] / (tau[i] - tau[j]);
    }
    x += basis * track.x[i];
    y += basis * track.y[i];
    noise_var += basis * basis * track.sigma[i] * track.sigma[i];
    remainder *= std::abs(tau[i]);
  }
  const double bound = p == 1   ? config_.max_speed_px_s
                       : p == 2 ? config_.max_accel_px_s2 / 2.0
                                : config_.max_jerk_px_s3 / 6.0;
  const double uncertainty = config_.n_sigma * std::sqrt(noise_var) + bound * remainder;
  const double half = uncertainty + track.radius_px + config_.margin_px;
  window.predicted_x_px = x;
  window.predicted_y_px = y;
  window.uncertainty_px = uncertainty;
  window.reach_px = uncertainty + track.radius_px + 1.0;
  // NaN or huge (a wild point): wider than any window, so a full frame is taken.
  window.half_px =
      half < config_.max_half_px ? static_cast<int>(std::ceil(half)) : config_.max_half_px + 1;
  window.track_id = track.id;
}

bool WindowTracker::choose_full_frame(std::int64_t time_ns, FullFrameCause& cause) {
  const bool time_ok = have_time_ && time_ns > last_time_ns_ &&
                       1e-9 * double(time_ns - last_time_ns_) <= config_.max_gap_s;
  const bool time_back = have_time_ && time_ns <= last_time_ns_;
  if (time_back) {
    // Time went back (a clock step or a bad stamp): the history cannot be extrapolated.
    stats_.tracks_dropped += static_cast<std::uint64_t>(track_count_);
    track_count_ = 0;
  }
  // Drop the tracks predicted wholly outside the frame (marks leaving the image), then
  // predict the rest: the full pass uses the predictions to associate blobs too.
  int kept = 0;
  for (int i = 0; i < track_count_; ++i) {
    predict(tracks_[i], time_ns, windows_[i]);
    const Window& w = windows_[i];
    const double reach = w.half_px;
    const bool outside = !(w.predicted_x_px + reach >= 0 && w.predicted_y_px + reach >= 0 &&
                           w.predicted_x_px - reach <= frame_width_ - 1 &&
                           w.predicted_y_px - reach <= frame_height_ - 1);
    if (outside) {
      ++stats_.tracks_dropped;
      continue;
    }
    tracks_[kept] = tracks_[i];
    windows_[kept] = windows_[i];
    ++kept;
  }
  track_count_ = kept;

  if (time_back) {
    cause = FullFrameCause::kTimeGap;
  } else if (track_count_ == 0) {
    cause = FullFrameCause::kNoTracks;
  } else if (!time_ok) {
    cause = FullFrameCause::kTimeGap;
  } else if (full_frame_requested_) {
    cause = FullFrameCause::kRequested;
  } else if (have_pending_cause_) {
    cause = pending_cause_;
  } else if (too_many_marks_) {
    cause = FullFrameCause::kTooManyMarks;
  } else if (frames_since_full_ + 1 >= config_.full_frame_interval) {
    cause = FullFrameCause::kPeriodic;
  } else {
    for (int i = 0; i < track_count_; ++i) {
      if (windows_[i].half_px > config_.max_half_px) {
        cause = FullFrameCause::kWideWindow;
        return true;
      }
    }
    std::array<long, kMaxTracks> cx, cy;
    for (int i = 0; i < track_count_; ++i) {
      cx[i] = std::lround(windows_[i].predicted_x_px);
      cy[i] = std::lround(windows_[i].predicted_y_px);
    }
    for (int i = 0; i < track_count_; ++i) {
      for (int j = i + 1; j < track_count_; ++j) {
        if (touch(windows_[i], cx[i], cy[i], windows_[j], cx[j], cy[j])) {
          cause = FullFrameCause::kWindowsTouch;
          return true;
        }
      }
    }
    return false;
  }
  return true;
}

int WindowTracker::refuse(int rc) {
  ++stats_.frames_refused;
  stats_.tracks_dropped += static_cast<std::uint64_t>(track_count_);
  track_count_ = 0;
  return rc;
}

int WindowTracker::process(const frame::FrameView& frame, std::int64_t time_ns, std::span<Blob> out,
                           std::span<std::uint32_t> track_ids) {
  ++stats_.frames;
  frame_width_ = frame.width;
  frame_height_ = frame.height;
  FullFrameCause cause = FullFrameCause::kNoTracks;
  int n = 0;
  if (choose_full_frame(time_ns, cause)) {
    n = full_pass(frame, time_ns, cause, out, track_ids);
  } else {
    n = windowed_pass(frame, time_ns, out, track_ids, cause);
    if (n == -EAGAIN) n = full_pass(frame, time_ns, cause, out, track_ids);
  }
  if (n >= 0) {
    last_time_ns_ = time_ns;
    have_time_ = true;
  }
  return n;
}

bool WindowTracker::window_cuts_blob(const Roi& roi, const Blob& blob) const {
  if ((blob.flags & centroid::blob_flags::kBorder) == 0) return false;
  // kBorder means the mark touches its region's edge. Where that edge is the frame's own, the
  // full frame would flag it too; only an edge inside the frame cuts the mark short.
  const double reach = blob.diameter_px / 2.0 + 1.0;
  const bool left_inside = roi.x > 0, top_inside = roi.y > 0;
  const bool right_inside = roi.x + roi.width < frame_width_;
  const bool bottom_inside = roi.y + roi.height < frame_height_;
  if (left_inside && top_inside && right_inside && bottom_inside) return true;
  return (left_inside && blob.x_px - reach <= roi.x) ||
         (top_inside && blob.y_px - reach <= roi.y) ||
         (right_inside && blob.x_px + reach >= roi.x + roi.width - 1) ||
         (bottom_inside && blob.y_px + reach >= roi.y + roi.height - 1);
}

int WindowTracker::windowed_pass(const frame::FrameView& frame, std::int64_t time_ns,
                                 std::span<Blob> out, std::span<std::uint32_t> track_ids,
                                 FullFrameCause& failure) {
  for (int i = 0; i < track_count_; ++i) {
    const Window& w = windows_[i];
    const int cx = static_cast<int>(std::lround(w.predicted_x_px));
    const int cy = static_cast<int>(std::lround(w.predicted_y_px));
    rois_[i] = Roi{cx - w.half_px, cy - w.half_px, 2 * w.half_px + 1, 2 * w.half_px + 1};
    blob_of_track_[i] = -1;
  }
  stats_.windows_tried += static_cast<std::uint64_t>(track_count_);
  const int m =
      centroider_.process(frame, std::span<const Roi>(rois_.data(), track_count_), window_blobs_);
  if (m < 0) return refuse(m);

  // No window reaches another track's mark, so each blob is its window's mark, or a second
  // mark (one not tracked, or a crossing one) that only a full pass can sort out.
  bool extra = m >= kWindowBlobs;  // full: a blob may have been dropped
  for (int b = 0; b < m; ++b) {
    const Blob& blob = window_blobs_[b];
    // The window holding the blob whose prediction is nearest (margins may overlap).
    int owner = -1;
    double owner_d2 = 0;
    for (int i = 0; i < track_count_; ++i) {
      const Roi& r = rois_[i];
      if (!(blob.x_px >= r.x - 0.5 && blob.x_px < r.x + r.width - 0.5 && blob.y_px >= r.y - 0.5 &&
            blob.y_px < r.y + r.height - 0.5))
        continue;
      const double d2 = std::pow(blob.x_px - windows_[i].predicted_x_px, 2) +
                        std::pow(blob.y_px - windows_[i].predicted_y_px, 2);
      if (owner < 0 || d2 < owner_d2) {
        owner = i;
        owner_d2 = d2;
      }
    }
    if (owner < 0 || blob_of_track_[owner] >= 0) {
      extra = true;
      continue;
    }
    blob_of_track_[owner] = b;
  }
  int lost = 0;
  for (int i = 0; i < track_count_; ++i) {
    const int b = blob_of_track_[i];
    if (b < 0 || window_cuts_blob(rois_[i], window_blobs_[b])) {
      blob_of_track_[i] = -1;
      ++lost;
    }
  }
  stats_.marks_lost += static_cast<std::uint64_t>(lost);
  stats_.last_windows = track_count_;
  if (lost > 0 || extra) {
    failure = lost > 0 ? FullFrameCause::kMarkLost : FullFrameCause::kNewMarkInWindow;
    if (config_.recover_in_same_frame) return -EAGAIN;
    have_pending_cause_ = true;
    pending_cause_ = failure;
  }

  ++stats_.windowed_frames;
  ++frames_since_full_;
  stats_.last_full_frame = false;
  int written = 0;
  for (int i = 0; i < track_count_; ++i) {
    const int b = blob_of_track_[i];
    if (b < 0) continue;  // lost, without same-frame recovery: the track waits for a full frame
    add_point(tracks_[i], time_ns, window_blobs_[b]);
    if (written < static_cast<int>(out.size())) {
      out[written] = window_blobs_[b];
      if (written < static_cast<int>(track_ids.size())) track_ids[written] = tracks_[i].id;
      ++written;
    }
  }
  return written;
}

int WindowTracker::full_pass(const frame::FrameView& frame, std::int64_t time_ns,
                             FullFrameCause cause, std::span<Blob> out,
                             std::span<std::uint32_t> track_ids) {
  ++stats_.full_frames;
  ++stats_.full_frames_by_cause[static_cast<int>(cause)];
  stats_.last_full_frame = true;
  stats_.last_cause = cause;
  stats_.last_windows = 0;
  full_frame_requested_ = false;
  have_pending_cause_ = false;
  frames_since_full_ = 0;
  const int n = centroider_.process(frame, out);
  if (n < 0) return refuse(n);

  // Each track takes the nearest blob within its window that no earlier track took.
  for (int i = 0; i < track_count_; ++i) {
    const Window& w = windows_[i];
    const double gate = config_.gate_halves * w.half_px;
    int best = -1;
    double best_d2 = gate * gate;
    for (int b = 0; b < n; ++b) {
      const double dx = out[b].x_px - w.predicted_x_px, dy = out[b].y_px - w.predicted_y_px;
      const double d2 = dx * dx + dy * dy;
      if (d2 > best_d2) continue;
      bool taken = false;
      for (int k = 0; k < i && !taken; ++k)
        taken = blob_of_track_[k] == b;
      if (taken) continue;
      best = b;
      best_d2 = d2;
    }
    blob_of_track_[i] = best;
  }
  int count = 0;
  for (int i = 0; i < track_count_; ++i) {
    const int b = blob_of_track_[i];
    if (b < 0) {
      ++stats_.tracks_dropped;
      continue;
    }
    next_tracks_[count] = tracks_[i];
    add_point(next_tracks_[count], time_ns, out[b]);
    if (b < static_cast<int>(track_ids.size())) track_ids[b] = next_tracks_[count].id;
    ++count;
  }
  too_many_marks_ = false;
  for (int b = 0; b < n; ++b) {
    bool matched = false;
    for (int i = 0; i < track_count_ && !matched; ++i)
      matched = blob_of_track_[i] == b;
    if (matched) continue;
    if (count >= kMaxTracks) {
      ++stats_.tracks_not_started;
      too_many_marks_ = true;
      if (b < static_cast<int>(track_ids.size())) track_ids[b] = 0;
      continue;
    }
    Track& track = next_tracks_[count++];
    track = Track{};
    track.id = next_id_++;
    add_point(track, time_ns, out[b]);
    ++stats_.tracks_started;
    if (b < static_cast<int>(track_ids.size())) track_ids[b] = track.id;
  }
  std::copy(next_tracks_.begin(), next_tracks_.begin() + count, tracks_.begin());
  track_count_ = count;
  return n;
}

}  // namespace storetrack::track
