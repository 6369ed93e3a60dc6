// FrameSource: where the unit's frames come from (V4L2 camera, simulator, replayed files).
//
// The per-frame path must not allocate or throw: acquire() hands out a view of a buffer the
// source owns (for V4L2, the mmap'd driver buffer itself) and release() gives it back.
// Every call returns 0 on success or a negative errno value (-EAGAIN: no frame before the
// timeout; -ENODATA: end of a finite source such as a replay).
#pragma once

#include <cstdint>

#include "storetrack/time/time.hpp"

namespace storetrack::frame {

enum class PixelFormat : std::uint8_t {
  kMono8 = 0,   ///< V4L2 GREY / Y8
  kMono16 = 1,  ///< V4L2 Y16 (also Y10 in 16-bit containers); little-endian, LSB-aligned
};

/// A borrowed view of one frame. Pixel (x, y) of a kMono8 frame is
/// pixels[y * stride_bytes + x]; pixel centres are at integer coordinates (docs/conventions.md).
struct FrameView {
  const std::uint8_t* pixels = nullptr;
  int width = 0;
  int height = 0;
  int stride_bytes = 0;
  PixelFormat format = PixelFormat::kMono8;
  int bits_per_pixel = 8;      ///< significant bits (8, 10, 12 or 16)
  std::uint32_t sequence = 0;  ///< the source's own frame counter (V4L2 buffer sequence)
  time::MonotonicNs timestamp_mono_ns = 0;  ///< start of exposure, unit CLOCK_MONOTONIC
  std::uint32_t exposure_ns = 0;            ///< exposure duration
  int buffer_index = -1;                    ///< the source's handle, for release()
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  virtual int start() = 0;
  virtual int stop() = 0;
  /// Waits up to timeout_ms for the next frame and fills `frame`.
  virtual int acquire(FrameView& frame, int timeout_ms) = 0;
  /// Returns a frame obtained by acquire() to the source.
  virtual int release(const FrameView& frame) = 0;
  /// Human-readable identity for error messages ("/dev/video0", "sim camera 1", ...).
  virtual const char* name() const = 0;
};

}  // namespace storetrack::frame
