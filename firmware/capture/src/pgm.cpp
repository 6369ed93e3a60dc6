#include "storetrack/capture/pgm.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <vector>

namespace storetrack::capture {
namespace {

bool is_space(std::uint8_t c) {
  return c == ' ' || c == '\t' || c == '\n' || c == '\r';
}

// Reads one unsigned decimal header field, skipping whitespace and '#' comments.
bool next_int(std::span<const std::uint8_t> b, std::size_t& pos, int& value) {
  for (;;) {
    while (pos < b.size() && is_space(b[pos]))
      ++pos;
    if (pos < b.size() && b[pos] == '#') {  // to the next CR or LF (netpbm)
      while (pos < b.size() && b[pos] != '\n' && b[pos] != '\r')
        ++pos;
      continue;
    }
    break;
  }
  if (pos >= b.size() || b[pos] < '0' || b[pos] > '9') return false;
  long v = 0;
  while (pos < b.size() && b[pos] >= '0' && b[pos] <= '9') {
    v = v * 10 + (b[pos] - '0');
    if (v > 1'000'000) return false;
    ++pos;
  }
  value = static_cast<int>(v);
  return true;
}

}  // namespace

int parse_pgm_header(std::span<const std::uint8_t> b, PgmHeader& out) {
  if (b.size() < 2 || b[0] != 'P' || b[1] != '5') return -EINVAL;
  std::size_t pos = 2;
  if (!next_int(b, pos, out.width) || !next_int(b, pos, out.height) ||
      !next_int(b, pos, out.maxval)) {
    return -EINVAL;
  }
  if (out.width <= 0 || out.height <= 0 || out.maxval <= 0 || out.maxval > 65535) return -EINVAL;
  if (pos >= b.size() || !is_space(b[pos])) return -EINVAL;
  out.data_offset = pos + 1;  // exactly one whitespace byte ends the header
  const std::size_t need = static_cast<std::size_t>(out.width) *
                           static_cast<std::size_t>(out.height) *
                           static_cast<std::size_t>(out.bytes_per_pixel());
  if (b.size() < out.data_offset + need) return -EINVAL;
  return 0;
}

long read_file_into(const char* path, std::span<std::uint8_t> buffer) {
  const int fd = open(path, O_RDONLY | O_CLOEXEC);
  if (fd < 0) return -errno;
  std::size_t total = 0;
  for (;;) {
    if (total == buffer.size()) {  // file larger than the buffer
      std::uint8_t probe;
      const ssize_t extra = read(fd, &probe, 1);
      close(fd);
      return extra == 0 ? static_cast<long>(total) : -EFBIG;
    }
    const ssize_t n = read(fd, buffer.data() + total, buffer.size() - total);
    if (n < 0) {
      if (errno == EINTR) continue;
      const int err = errno;
      close(fd);
      return -err;
    }
    if (n == 0) break;
    total += static_cast<std::size_t>(n);
  }
  close(fd);
  return static_cast<long>(total);
}

int write_pgm(const std::string& path, const frame::FrameView& f) {
  std::FILE* fp = std::fopen(path.c_str(), "wb");
  if (fp == nullptr) return -errno;
  const bool wide = f.format == frame::PixelFormat::kMono16;
  const int maxval = wide ? (1 << f.bits_per_pixel) - 1 : 255;
  std::fprintf(fp, "P5\n%d %d\n%d\n", f.width, f.height, maxval);
  std::vector<std::uint8_t> row(static_cast<std::size_t>(f.width * (wide ? 2 : 1)));
  bool ok = true;
  for (int y = 0; y < f.height && ok; ++y) {
    const std::uint8_t* src = f.pixels + static_cast<std::ptrdiff_t>(y) * f.stride_bytes;
    if (wide) {
      for (int x = 0; x < f.width; ++x) {  // little-endian in memory -> big-endian on disk
        row[static_cast<std::size_t>(2 * x)] = src[2 * x + 1];
        row[static_cast<std::size_t>(2 * x + 1)] = src[2 * x];
      }
    } else {
      for (int x = 0; x < f.width; ++x)
        row[static_cast<std::size_t>(x)] = src[x];
    }
    ok = std::fwrite(row.data(), 1, row.size(), fp) == row.size();
  }
  const bool closed = std::fclose(fp) == 0;
  return ok && closed ? 0 : -EIO;
}

}  // namespace storetrack::capture
