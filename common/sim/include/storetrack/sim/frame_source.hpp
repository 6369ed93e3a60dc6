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
class SimFrameSource : public frame::FrameSource {
 public:
  /// `pace_realtime`: acquire() sleeps so frames come at the scenario frame rate.
  /// `first_exposure`: the first exposure delivered (a unit started mid-run). `pace_hz` > 0
  /// paces at that rate instead of the scenario's (slow motion: the time stamps stay the
  /// scenario's, only the delivery is slower, for machines that cannot render in real time).
  SimFrameSource(const Simulator& sim, int camera_index, int ring_size = 4,
                 bool pace_realtime = false, int first_exposure = 0, double pace_hz = 0);
  int start() override;
  int stop() override;
  int acquire(frame::FrameView& frame, int timeout_ms) override;
  int release(const frame::FrameView& frame) override;
  const char* name() const override { return name_.c_str(); }

  int frames_delivered() const { return next_exposure_ - first_exposure_; }

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
  SpotRenderer renderer_;
  std::string name_;
  time::MonotonicNs start_mono_ns_ = 0;
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
