// libFuzzer target: the replay source's PGM reader (firmware/capture ReplayFrameSource over a
// directory holding one arbitrary file frame.pgm, no triggers.csv) as storetrack-unit runs it:
// start(), then acquire() twice (looping). Properties checked (abort when violated), beyond
// "no crash, no UB":
//  - acquire() gives 0 or -EINVAL; an accepted frame is the file as netpbm P5 defines it, read
//    here independently (magic, whitespace and '#' comments to the end of the line, width,
//    height, maxval in [1, 65535], one whitespace byte, the raster; 16-bit big-endian and
//    at most maxval);
//  - a P5 file of at most 4096 x 4096 that this reading accepts is accepted by the reader;
//  - a 16-bit frame's pixels fit its significant bits (a pixel above maxval is no P5 file);
//  - the second acquire (the loop) gives the same pixels, the next sequence number, and a time
//    stamp one default period later.
#include <cerrno>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>
#include <string_view>
#include <vector>

#include "scratch_directory.hpp"
#include "storetrack/capture/replay_frame_source.hpp"

namespace {

namespace capture = storetrack::capture;
namespace frame = storetrack::frame;
namespace fuzz = storetrack::fuzz;

struct NetpbmImage {
  long width = 0, height = 0, maxval = 0;
  std::size_t raster_offset = 0;
};

bool is_whitespace(std::uint8_t c) {
  return c == ' ' || c == '\t' || c == '\n' || c == '\r';
}

// One header number after whitespace and comments; false when there is none or it exceeds cap.
bool header_number(const std::uint8_t* p, std::size_t n, std::size_t& pos, long cap, long& out) {
  for (;;) {
    while (pos < n && is_whitespace(p[pos]))
      ++pos;
    if (pos < n && p[pos] == '#') {
      while (pos < n && p[pos] != '\n' && p[pos] != '\r')
        ++pos;
      continue;
    }
    break;
  }
  if (pos >= n || p[pos] < '0' || p[pos] > '9') return false;
  out = 0;
  while (pos < n && p[pos] >= '0' && p[pos] <= '9') {
    out = out * 10 + (p[pos] - '0');
    if (out > cap) return false;
    ++pos;
  }
  return true;
}

// netpbm's P5 (https://netpbm.sourceforge.net/doc/pgm.html), sizes capped at `cap` each.
bool read_netpbm(const std::uint8_t* p, std::size_t n, long cap, NetpbmImage& img) {
  if (n < 2 || p[0] != 'P' || p[1] != '5') return false;
  std::size_t pos = 2;  // netpbm's own reader takes "P54 4 255" too
  if (!header_number(p, n, pos, cap, img.width) || !header_number(p, n, pos, cap, img.height) ||
      !header_number(p, n, pos, 65535, img.maxval))
    return false;
  if (img.width < 1 || img.height < 1 || img.maxval < 1) return false;
  if (pos >= n || !is_whitespace(p[pos])) return false;
  img.raster_offset = pos + 1;
  const std::size_t raster = static_cast<std::size_t>(img.width) *
                             static_cast<std::size_t>(img.height) * (img.maxval > 255 ? 2 : 1);
  if (n - img.raster_offset < raster) return false;
  // Each gray value is in [0, maxval]. An 8-bit frame holds any byte in its 8 significant
  // bits, so only a 16-bit one is held to it.
  for (std::size_t i = 0; img.maxval > 255 && i < raster; i += 2) {
    const long gray = long{p[img.raster_offset + i]} << 8 | p[img.raster_offset + i + 1];
    if (gray > img.maxval) return false;
  }
  return true;
}

std::uint32_t pixel(const frame::FrameView& f, long i) {
  if (f.format == frame::PixelFormat::kMono8) return f.pixels[i];
  std::uint16_t v;
  std::memcpy(&v, f.pixels + 2 * i, 2);
  return v;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  fuzz::ScratchDirectory dir("replay");
  dir.write("frame.pgm", std::string_view(reinterpret_cast<const char*>(data), size));
  capture::ReplayConfig config;
  config.directory = dir.path();
  config.loop = true;
  capture::ReplayFrameSource source(config);
  if (source.start() != 0) std::abort();  // the file exists: start() never reads it
  frame::FrameView first;
  const int rc = source.acquire(first, 0);
  NetpbmImage img;
  const bool small_p5 = read_netpbm(data, size, 4096, img);
  if (rc != 0) {
    if (rc != -EINVAL || small_p5) std::abort();
    return 0;
  }
  if (!read_netpbm(data, size, 1'000'000, img)) std::abort();  // accepted what is no P5 file
  if (first.width != img.width || first.height != img.height) std::abort();
  const bool wide = img.maxval > 255;
  if (first.format != (wide ? frame::PixelFormat::kMono16 : frame::PixelFormat::kMono8))
    std::abort();
  if (first.stride_bytes != first.width * (wide ? 2 : 1)) std::abort();
  const long count = img.width * img.height;
  const std::uint8_t* raster = data + img.raster_offset;
  const std::uint32_t significant_max = (std::uint32_t{1} << first.bits_per_pixel) - 1;
  if (significant_max < static_cast<std::uint32_t>(img.maxval)) std::abort();
  for (long i = 0; i < count; ++i) {
    const std::uint32_t written =
        wide ? std::uint32_t{raster[2 * i]} << 8 | raster[2 * i + 1] : raster[i];
    if (pixel(first, i) != written) std::abort();
    if (wide && written > significant_max) std::abort();
  }
  const std::vector<std::uint8_t> first_pixels(
      first.pixels, first.pixels + static_cast<std::size_t>(first.stride_bytes) * img.height);
  const std::uint32_t first_sequence = first.sequence;
  const std::int64_t first_time = first.timestamp_mono_ns;
  if (source.release(first) != 0) std::abort();
  frame::FrameView again;
  if (source.acquire(again, 0) != 0) std::abort();
  if (again.sequence != first_sequence + 1) std::abort();
  if (again.timestamp_mono_ns != first_time + config.default_period_ns) std::abort();
  if (std::memcmp(again.pixels, first_pixels.data(), first_pixels.size()) != 0) std::abort();
  source.release(again);
  return 0;
}
