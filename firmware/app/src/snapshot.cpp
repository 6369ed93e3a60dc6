#include "snapshot.hpp"

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "storetrack/png/png_writer.hpp"

namespace storetrack::unit {
namespace {

double pixel(const frame::FrameView& f, int x, int y) {
  const std::uint8_t* row = f.pixels + static_cast<std::ptrdiff_t>(y) * f.stride_bytes;
  if (f.format == frame::PixelFormat::kMono16) {
    return static_cast<double>(row[2 * x] | (row[2 * x + 1] << 8));
  }
  return row[x];
}

std::uint8_t display(const frame::FrameView& f, int x, int y) {
  const double v = pixel(f, x, y);
  const int shift = f.format == frame::PixelFormat::kMono16 ? f.bits_per_pixel - 8 : 0;
  return static_cast<std::uint8_t>(std::clamp(v / (1 << shift), 0.0, 255.0));
}

// 3x5 glyphs, rows top to bottom, 3 bits per row (MSB = left column).
struct Glyph {
  char c;
  std::array<std::uint8_t, 5> rows;
};
constexpr Glyph kFont[] = {
    {'0', {7, 5, 5, 5, 7}}, {'1', {2, 6, 2, 2, 7}}, {'2', {7, 1, 7, 4, 7}}, {'3', {7, 1, 7, 1, 7}},
    {'4', {5, 5, 7, 1, 1}}, {'5', {7, 4, 7, 1, 7}}, {'6', {7, 4, 7, 5, 7}}, {'7', {7, 1, 1, 1, 1}},
    {'8', {7, 5, 7, 5, 7}}, {'9', {7, 5, 7, 1, 7}}, {'.', {0, 0, 0, 0, 2}}, {'s', {0, 3, 6, 1, 6}},
    {'S', {7, 4, 7, 1, 7}}, {'B', {6, 5, 6, 5, 6}}, {'M', {5, 7, 7, 5, 5}}, {'E', {7, 4, 6, 4, 7}},
    {'-', {0, 0, 7, 0, 0}}, {' ', {0, 0, 0, 0, 0}},
};

struct Canvas {
  int width, height;
  std::vector<std::uint8_t> rgb;
  void put(int x, int y, std::array<std::uint8_t, 3> c) {
    if (x < 0 || y < 0 || x >= width || y >= height) return;
    std::memcpy(&rgb[(static_cast<std::size_t>(y) * width + x) * 3], c.data(), 3);
  }
  void circle(double cx, double cy, double r, std::array<std::uint8_t, 3> c) {
    const int steps = std::max(16, static_cast<int>(r * 8));
    for (int i = 0; i < steps; ++i) {
      const double a = 2 * M_PI * i / steps;
      put(static_cast<int>(std::lround(cx + r * std::cos(a))),
          static_cast<int>(std::lround(cy + r * std::sin(a))), c);
    }
  }
  void text(int x, int y, const std::string& s, std::array<std::uint8_t, 3> c, int scale = 2) {
    for (char ch : s) {
      for (const Glyph& g : kFont) {
        if (g.c != ch) continue;
        for (int r = 0; r < 5; ++r) {
          for (int col = 0; col < 3; ++col) {
            if (!(g.rows[static_cast<std::size_t>(r)] & (4 >> col))) continue;
            for (int dy = 0; dy < scale; ++dy) {
              for (int dx = 0; dx < scale; ++dx)
                put(x + col * scale + dx, y + r * scale + dy, c);
            }
          }
        }
      }
      x += 4 * scale;
    }
  }
};

std::array<std::uint8_t, 3> colour(std::uint8_t flags) {
  if (flags & centroid::blob_flags::kSaturated) return {255, 40, 40};
  if (flags & (centroid::blob_flags::kMerged | centroid::blob_flags::kElongated))
    return {255, 0, 255};
  if (flags & centroid::blob_flags::kBorder) return {255, 220, 0};
  return {0, 255, 0};
}

/// `path` opened for writing, else nullptr with *error naming it and errno's reason.
std::FILE* open_for_writing(const std::string& path, std::string* error) {
  std::FILE* fp = std::fopen(path.c_str(), "wb");
  if (fp == nullptr && error) *error = path + ": " + std::strerror(errno);
  return fp;
}

/// Closes `fp`: `path` when the data reached the file, else "" with *error set.
std::string close_written(std::FILE* fp, const std::string& path, std::string* error) {
  if (std::fclose(fp) == 0) return path;
  if (error) *error = path + ": write failed";
  return {};
}

std::string write_canvas_png(const std::string& stem, const Canvas& canvas, std::string* error) {
  const std::string path = stem + ".png";
  std::FILE* fp = open_for_writing(path, error);
  if (fp == nullptr) return {};
  if (!png::write_png(fp, canvas.rgb.data(), canvas.width, canvas.height, png::Channels::kRgb)) {
    std::fclose(fp);
    if (error) *error = path + ": libpng write failed";
    return {};
  }
  return close_written(fp, path, error);
}

// No libpng on this build: a grey PGM with the overlay burnt in (marks white on dark).
std::string write_canvas_pgm(const std::string& stem, const Canvas& canvas, std::string* error) {
  const std::string path = stem + ".pgm";
  std::FILE* fp = open_for_writing(path, error);
  if (fp == nullptr) return {};
  std::fprintf(fp, "P5\n%d %d\n255\n", canvas.width, canvas.height);
  std::vector<std::uint8_t> row(static_cast<std::size_t>(canvas.width));
  for (int y = 0; y < canvas.height; ++y) {
    for (int x = 0; x < canvas.width; ++x) {
      const std::uint8_t* p = &canvas.rgb[(static_cast<std::size_t>(y) * canvas.width + x) * 3];
      const bool overlay = !(p[0] == p[1] && p[1] == p[2]);
      row[static_cast<std::size_t>(x)] = overlay ? 255 : p[0];
    }
    std::fwrite(row.data(), 1, row.size(), fp);
  }
  return close_written(fp, path, error);
}

}  // namespace

std::string flag_letters(std::uint8_t flags) {
  std::string s;
  if (flags & centroid::blob_flags::kSaturated) s += 'S';
  if (flags & centroid::blob_flags::kBorder) s += 'B';
  if (flags & centroid::blob_flags::kMerged) s += 'M';
  if (flags & centroid::blob_flags::kElongated) s += 'E';
  return s.empty() ? "-" : s;
}

MarkFigures measure_mark(const frame::FrameView& f, const centroid::Blob& b,
                         const centroid::CentroidConfig& noise) {
  MarkFigures m;
  m.peak_dn = b.peak_dn;
  const int half = std::clamp(static_cast<int>(std::ceil(b.diameter_px)) + 3, 3, 40);
  const int cx = static_cast<int>(std::lround(b.x_px));
  const int cy = static_cast<int>(std::lround(b.y_px));
  int area_half = 0;
  for (int y = std::max(0, cy - half); y <= std::min(f.height - 1, cy + half); ++y) {
    for (int x = std::max(0, cx - half); x <= std::min(f.width - 1, cx + half); ++x) {
      if (pixel(f, x, y) - b.background_dn >= 0.5 * b.peak_dn) ++area_half;
    }
  }
  m.fwhm_px = 2.0 * std::sqrt(area_half / M_PI);
  // CCD equation (Howell, Handbook of CCD Astronomy, eq. 4.4) with the centroider's model.
  const double g = noise.gain_e_per_dn;
  const double flux_e = std::max(0.0, static_cast<double>(b.flux_dn) * g);
  const double npix = std::max(1.0, static_cast<double>(b.area_px));
  const double bg_e = std::max(0.0, (b.background_dn - noise.black_level_dn) * g);
  const double noise_e =
      std::sqrt(flux_e + npix * (bg_e + noise.read_noise_e * noise.read_noise_e));
  m.snr = noise_e > 0 ? flux_e / noise_e : 0;
  return m;
}

void print_mark_table(std::FILE* out, const frame::FrameView& f,
                      std::span<const centroid::Blob> blobs,
                      const centroid::CentroidConfig& noise) {
  std::fprintf(out, "frame %ux%d seq %u: %zu marks\n", static_cast<unsigned>(f.width), f.height,
               f.sequence, blobs.size());
  std::fprintf(out, "%4s %10s %10s %8s %8s %7s %8s %6s\n", "idx", "x_px", "y_px", "sigma_px",
               "peak_dn", "fwhm_px", "snr", "flags");
  for (std::size_t i = 0; i < blobs.size(); ++i) {
    const MarkFigures m = measure_mark(f, blobs[i], noise);
    std::fprintf(out, "%4zu %10.3f %10.3f %8.4f %8.1f %7.2f %8.1f %6s\n", i, blobs[i].x_px,
                 blobs[i].y_px, blobs[i].sigma_px, m.peak_dn, m.fwhm_px, m.snr,
                 flag_letters(blobs[i].flags).c_str());
  }
}

std::string write_overlay(const std::string& stem, const frame::FrameView& f,
                          std::span<const centroid::Blob> blobs, std::string* error) {
  Canvas canvas{f.width, f.height,
                std::vector<std::uint8_t>(static_cast<std::size_t>(f.width) * f.height * 3)};
  for (int y = 0; y < f.height; ++y) {
    for (int x = 0; x < f.width; ++x) {
      const std::uint8_t v = display(f, x, y);
      canvas.put(x, y, {v, v, v});
    }
  }
  for (std::size_t i = 0; i < blobs.size(); ++i) {
    const centroid::Blob& b = blobs[i];
    const auto c = colour(b.flags);
    canvas.circle(b.x_px, b.y_px, std::max(5.0, static_cast<double>(b.diameter_px) / 2 + 3), c);
    char label[64];
    std::snprintf(label, sizeof label, "%zu s%.3f %s", i, b.sigma_px,
                  flag_letters(b.flags).c_str());
    canvas.text(static_cast<int>(b.x_px) + 8, static_cast<int>(b.y_px) - 12, label, c);
  }
  return png::available() ? write_canvas_png(stem, canvas, error)
                          : write_canvas_pgm(stem, canvas, error);
}

}  // namespace storetrack::unit
