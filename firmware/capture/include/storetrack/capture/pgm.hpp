// Binary PGM (netpbm P5) images: the replay format and the snapshot fallback.
// 8-bit when maxval <= 255, else 16-bit big-endian on disk (netpbm), host order in memory.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

#include "storetrack/frame/frame_source.hpp"

namespace storetrack::capture {

struct PgmHeader {
  int width = 0;
  int height = 0;
  int maxval = 0;
  std::size_t data_offset = 0;  ///< bytes before the first pixel
  int bytes_per_pixel() const { return maxval > 255 ? 2 : 1; }
};

/// Parses a P5 header from the start of a file's bytes. Returns 0 or -EINVAL (bad magic,
/// dimensions, maxval, or truncated data). No allocation.
int parse_pgm_header(std::span<const std::uint8_t> bytes, PgmHeader& out);

/// Reads a whole file into `buffer` (which must be large enough); returns bytes or -errno.
/// No allocation: the replay source sizes its buffer once at start().
long read_file_into(const char* path, std::span<std::uint8_t> buffer);

/// Writes a frame as P5 (8-bit, or 16-bit with maxval 2^bits - 1). Returns 0 or -errno.
int write_pgm(const std::string& path, const frame::FrameView& frame);

}  // namespace storetrack::capture
