// ReplayFrameSource: frames from a directory of PGM files, so the unit runs with no camera.
//
// Directory layout (docs/unit-config.md, "Replay directory"):
//   triggers.csv   optional; a header line naming the columns, then one line per frame.
//                  Needed columns (any order, others ignored): file, trigger_seq,
//                  exposure_start_mono_ns, exposure_start_tai_ns, exposure_ns; storetrack-sim's
//                  reported_start_mono_ns / reported_start_tai_ns are accepted for the
//                  exposure-start columns (write_frame_sequence() in common/sim). File names
//                  are relative to the directory. Lines starting with '#' are comments.
//   *.pgm          P5 images (8 or 16 bit). Without triggers.csv every *.pgm is replayed in
//                  name order with sequence = index and time stamps at the configured period.
// The FrameView's sequence is the trigger_seq of the file and its time stamp the exposure
// start; tai_ns() gives the recorded TAI of the frame last acquired.
// All file names and the largest file size are read at start(); acquire() reads one file into
// a buffer allocated there (no per-frame allocation).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "storetrack/frame/frame_source.hpp"

namespace storetrack::capture {

struct ReplayConfig {
  std::string directory;
  double rate_hz = 0.0;  ///< 0: as fast as the consumer takes them; else paced in real time
  bool loop = false;     ///< restart at the end instead of returning -ENODATA
  std::int64_t default_period_ns = 10'000'000;    ///< without triggers.csv
  std::uint32_t default_exposure_ns = 1'000'000;  ///< without triggers.csv
};

struct ReplayRecord {
  std::string file;
  std::uint32_t trigger_seq = 0;
  std::int64_t exposure_start_mono_ns = 0;
  std::int64_t exposure_start_tai_ns = 0;
  std::uint32_t exposure_ns = 0;
};

/// Parses triggers.csv text; throws std::runtime_error with the line number on bad input
/// (configuration time, not the frame path).
std::vector<ReplayRecord> parse_trigger_csv(const std::string& text);

class ReplayFrameSource final : public frame::FrameSource {
 public:
  explicit ReplayFrameSource(ReplayConfig config);

  int start() override;
  int stop() override { return 0; }
  int acquire(frame::FrameView& frame, int timeout_ms) override;
  int release(const frame::FrameView& frame) override;
  const char* name() const override { return config_.directory.c_str(); }

  const std::string& error() const { return error_; }
  std::size_t size() const { return records_.size(); }
  /// Recorded TAI exposure start of the last acquired frame.
  std::int64_t tai_ns() const { return last_tai_ns_; }

 private:
  ReplayConfig config_;
  std::vector<ReplayRecord> records_;
  std::vector<std::string> paths_;
  std::vector<std::uint8_t> file_buffer_;
  std::vector<std::uint8_t> pixels_;  ///< host-order pixels (16-bit byte-swapped from disk)
  std::size_t next_ = 0;
  std::int64_t last_tai_ns_ = 0;
  std::int64_t pace_start_mono_ns_ = 0;
  std::uint64_t loops_ = 0;
  std::int64_t loop_offset_ns_ = 0;  ///< added to the recorded times: the loops so far
  bool in_use_ = false;
  std::string error_;
};

}  // namespace storetrack::capture
