// SimFrameSource: simulator frames through the firmware's FrameSource interface, and PGM
// sequences + trigger-timestamp files for replay (format in common/sim/README.md).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "storetrack/frame/frame_source.hpp"
#include "storetrack/sim/render.hpp"
#include "storetrack/sim/simulator.hpp"

namespace storetrack::sim {

/// Renders exposures 0..N-1 of one camera on demand into a preallocated ring of buffers
/// (no allocation per frame after start()). acquire() returns -ENODATA after the last exposure,
/// -EBUSY when every buffer is held by the caller, -EINVAL when not started.
/// FrameView.sequence = trigger sequence number; timestamp_mono_ns = the exposure start as the
/// unit stamps it (same clock model as Simulator::observe).
///
/// A whole frame costs one random draw per pixel (about 5 ms at 1920 x 1024), too slow for
/// 400 fps. `background_pool` > 0 renders that many background frames at start() and then, per
/// exposure, draws only the spots' boxes (fresh noise) over background k % pool: the background
/// repeats with that period; the spots' mean is exact and their shot + read noise one Gaussian of
/// the exact variance, read from a table of 2^20 standard normals at a random offset per
/// exposure (SpotRenderer::render_spots_gaussian). The ring is then the pool (exposure k in
/// buffer k % pool; -EBUSY while the caller still holds it).
class SimFrameSource : public frame::FrameSource {
 public:
  /// `pace_realtime`: acquire() sleeps so frames come at the scenario frame rate.
  /// `first_exposure`: the first exposure delivered (a unit started mid-run). `pace_hz` > 0
  /// paces at that rate instead of the scenario's (slow motion: the time stamps stay the
  /// scenario's, only the delivery is slower, for machines that cannot render in real time).
  SimFrameSource(const Simulator& sim, int camera_index, int ring_size = 4,
                 bool pace_realtime = false, int first_exposure = 0, double pace_hz = 0,
                 int background_pool = 0);
  int start() override;
  int stop() override;
  int acquire(frame::FrameView& frame, int timeout_ms) override;
  int release(const frame::FrameView& frame) override;
  const char* name() const override { return name_.c_str(); }

  int frames_delivered() const { return next_exposure_ - first_exposure_; }

  /// Paced: exposure k is due at `origin` + k / pace rate (CLOCK_MONOTONIC, shared by every
  /// process of the machine, so units started at different times, or restarted, keep one
  /// trigger schedule as real ones do) instead of start() + (k - first_exposure) / rate.
  void set_pace_origin(time::MonotonicNs origin) { pace_origin_ns_ = origin; }

  /// Paced delivery against its schedule: how far behind it fell (a frame handed out later
  /// than its due time by more than one frame period is `late`). Zero when not paced.
  struct Pacing {
    std::int64_t max_behind_ns = 0;
    std::int64_t frames_late = 0;
    double frame_period_ns = 0;
  };
  Pacing pacing() const { return pacing_; }

 private:
  const Simulator& sim_;
  int camera_index_;
  bool pace_;
  bool started_ = false;
  int width_, height_;
  int first_exposure_ = 0;
  double pace_hz_ = 0;
  int next_exposure_ = 0;
  std::vector<std::vector<std::uint8_t>> buffers_;
  std::vector<bool> held_;
  int background_pool_ = 0;
  std::vector<std::vector<std::uint8_t>> backgrounds_;  // pristine copy of each pool buffer
  std::vector<std::vector<PixelBox>> drawn_;            // the spot boxes drawn in each buffer
  std::vector<float> unit_normals_;                     // the spots' noise (Gaussian approx.)
  Pacing pacing_;
  SpotRenderer renderer_;
  std::string name_;
  time::MonotonicNs start_mono_ns_ = 0;
  time::MonotonicNs pace_origin_ns_ = 0;  // 0: start_mono_ns_ for first_exposure_

  void render_pooled(int k, std::size_t slot);
};

/// Binary PGM (P5), 8-bit. Returns 0 or -errno.
int write_pgm(const std::string& path, const std::uint8_t* pixels, int width, int height,
              int stride);
/// Reads a binary 8-bit PGM; throws std::runtime_error naming the file on malformed input.
std::vector<std::uint8_t> read_pgm(const std::string& path, int& width, int& height);

/// Writes exposures [0, count) of one camera as DIR/frame_NNNNNN.pgm plus DIR/triggers.csv
/// (frame,trigger_seq,trigger_tai_ns,reported_start_tai_ns,reported_start_mono_ns,
/// exposure_ns,true_exposure_start_tai_ns,file). Throws std::runtime_error on I/O errors. count <
/// 0: all exposures.
void write_frame_sequence(const Simulator& sim, int camera_index, const std::string& dir,
                          int count = -1);

}  // namespace storetrack::sim
