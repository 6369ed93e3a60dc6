// Centroider: see the header and docs/centroiding.md for the method.
#include "storetrack/centroid/centroider.hpp"

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <numbers>
#include <stdexcept>
#include <string>

namespace storetrack::centroid {
namespace {

// Rows are scanned in chunks of kChunk pixels; background tiles are a multiple of it so one
// threshold applies to a whole chunk. A chunk is tested with 16-byte vector maxima (GCC/Clang
// vector extensions: SSE2 on x86-64, NEON on aarch64), and only chunks with a pixel above the
// threshold are looked at 16 bytes, then one pixel, at a time.
constexpr int kChunk = 128;
// Rows scan_region() asks the cache for ahead of the row it scans (ROI mode).
constexpr int kPrefetchRows = 4;

typedef std::uint8_t VecU8 __attribute__((vector_size(16)));
typedef std::uint16_t VecU16 __attribute__((vector_size(16)));
template <typename Pixel>
struct VectorOf;
template <>
struct VectorOf<std::uint8_t> {
  using type = VecU8;
};
template <>
struct VectorOf<std::uint16_t> {
  using type = VecU16;
};
template <typename Pixel>
constexpr int kLanes = 16 / static_cast<int>(sizeof(Pixel));

template <typename Pixel>
const Pixel* row_pointer(const frame::FrameView& frame, int y) {
  // The frame check guarantees 2-byte alignment of Mono16 rows.
  return static_cast<const Pixel*>(
      static_cast<const void*>(frame.pixels + static_cast<std::ptrdiff_t>(y) * frame.stride_bytes));
}

/// Asks the cache for the lines holding bytes [p, p + bytes) (bytes > 0).
inline void prefetch_span(const void* p, int bytes) {
  const char* first = static_cast<const char*>(p);
  for (int b = 0; b < bytes; b += 64) {
    __builtin_prefetch(first + b);
    // GCC deletes a loop of nothing but prefetches (it has no effect on the program's
    // semantics): the empty asm that "uses" each address keeps it.
    asm volatile("" : : "r"(first + b));
  }
  __builtin_prefetch(first + bytes - 1);
}

/// True if any of the kPixels pixels at p is above level.
template <typename Pixel, int kPixels>
inline bool any_above(const Pixel* p, Pixel level) {
  using Vec = typename VectorOf<Pixel>::type;
  Vec m;
  std::memcpy(&m, p, sizeof m);
  for (int i = kLanes<Pixel>; i < kPixels; i += kLanes<Pixel>) {
    Vec v;
    std::memcpy(&v, p + i, sizeof v);
    m = m > v ? m : v;
  }
  const auto above = m > level;
  std::uint64_t words[2];
  static_assert(sizeof above == sizeof words);
  std::memcpy(words, &above, sizeof words);
  return (words[0] | words[1]) != 0;
}

/// Gaussian window samples w[i] = exp(-(x0 + i - c)^2 / (2 s^2)) and offsets d[i] = x0 + i - c,
/// by the exact recurrence w[i+1] / w[i] = exp(-(2 d[i] + 1) / (2 s^2)) (ratios change by the
/// constant factor exp(-1 / s^2)): four exp() per axis instead of one per pixel.
void gaussian_window(int x0, int n, double c, double s, float* d, float* w) {
  const double k = 0.5 / (s * s);
  const int i0 = std::clamp(static_cast<int>(std::lround(c)) - x0, 0, n - 1);
  const double d0 = x0 + i0 - c;
  const double q = std::exp(-2.0 * k);
  const double w0 = std::exp(-k * d0 * d0);
  w[i0] = static_cast<float>(w0);
  double r = std::exp(-k * (2.0 * d0 + 1.0)), wi = w0;
  for (int i = i0 + 1; i < n; ++i) {
    wi *= r;
    w[i] = static_cast<float>(wi);
    r *= q;
  }
  r = std::exp(-k * (1.0 - 2.0 * d0));
  wi = w0;
  for (int i = i0 - 1; i >= 0; --i) {
    wi *= r;
    w[i] = static_cast<float>(wi);
    r *= q;
  }
  for (int i = 0; i < n; ++i)
    d[i] = static_cast<float>(x0 + i - c);
}

}  // namespace

Centroider::Centroider(const CentroidConfig& config, int max_width, int max_height)
    : config_(config), max_width_(max_width), max_height_(max_height) {
  auto fail = [](const std::string& what) {
    throw std::invalid_argument("centroid config: " + what);
  };
  if (max_width <= 0 || max_height <= 0 || max_width > 65535 || max_height > 65535)
    fail("max_width/max_height must be in 1..65535");
  if (config.threshold_dn <= 0 && !(config.threshold_sigma > 0))
    fail("threshold_sigma must be > 0");
  if (config.min_area_px < 1) fail("min_area_px must be >= 1");
  if (config.max_area_px < config.min_area_px) fail("max_area_px must be >= min_area_px");
  if (config.background_tile_px < 1) fail("background_tile_px must be >= 1");
  if (config.background_row_step_px < 1 || config.background_column_step_px < 1)
    fail("background_row_step_px and background_column_step_px must be >= 1");
  if (!(config.read_noise_e >= 0)) fail("read_noise_e must be >= 0");
  if (!(config.gain_e_per_dn > 0)) fail("gain_e_per_dn must be > 0");
  if (config.saturation_dn < 0) fail("saturation_dn must be >= 0");
  if (config.window_sigma_px < 0) fail("window_sigma_px must be >= 0");
  if (config.max_refine_iterations < 1) fail("max_refine_iterations must be >= 1");
  if (config.photon_weighting_steps < 1 || config.photon_weighting_steps > 8)
    fail("photon_weighting_steps must be in 1..8");
  if (!(config.window_radius_sigmas >= 2 && config.window_radius_sigmas <= 8))
    fail("window_radius_sigmas must be in [2, 8]");
  if (!(config.refine_tolerance_px > 0)) fail("refine_tolerance_px must be > 0");
  if (config.max_window_half_px < 3 || config.max_window_half_px > 64)
    fail("max_window_half_px must be in 3..64");
  if (!(config.max_axis_ratio >= 1)) fail("max_axis_ratio must be >= 1");
  if (!(config.merge_peak_fraction > 0 && config.merge_peak_fraction <= 1))
    fail("merge_peak_fraction must be in (0, 1]");
  if (!(config.merge_dip_fraction > 0 && config.merge_dip_fraction < 1))
    fail("merge_dip_fraction must be in (0, 1)");
  if (config.max_runs < 16) fail("max_runs must be >= 16");
  if (config.max_candidates < 1) fail("max_candidates must be >= 1");
  if (config.max_rois < 1) fail("max_rois must be >= 1");

  tile_px_ = (config.background_tile_px + kChunk - 1) / kChunk * kChunk;
  const int max_tiles_x = (max_width + tile_px_ - 1) / tile_px_;
  const int max_tiles_y = (max_height + tile_px_ - 1) / tile_px_;
  const int max_chunks = (max_width + kChunk - 1) / kChunk;
  runs_.resize(config.max_runs);
  parent_.resize(config.max_runs);
  label_.resize(config.max_runs);
  regions_.resize(config.max_rois);
  candidates_.resize(config.max_candidates);
  selected_.resize(config.max_candidates);
  tile_background_.resize(static_cast<size_t>(max_tiles_x) * max_tiles_y);
  tile_threshold_.resize(tile_background_.size());
  sorted_tiles_.resize(tile_background_.size());
  tile_wanted_.resize(tile_background_.size());
  row_threshold_.resize(max_chunks);
  chunk_tile_.resize(max_chunks);
  column_max_.resize(max_width);
  for (int c = 0; c < max_chunks; ++c)
    chunk_tile_[c] = c * kChunk / tile_px_;
  samples_.resize(static_cast<size_t>(tile_px_ / config.background_row_step_px + 1) *
                  (tile_px_ / config.background_column_step_px + 1));
  const int patch_side = 2 * config.max_window_half_px + 1;
  patch_.resize(static_cast<size_t>(patch_side) * patch_side);
  patch_keep_.resize(patch_.size());
  flat_dx_.resize(patch_.size());
  flat_dy_.resize(patch_.size());
  flat_g_.resize(patch_.size());
  wx_.resize(patch_side);
  wy_.resize(patch_side);
  dx_.resize(patch_side);
  dy_.resize(patch_side);
  tiles_x_ = max_tiles_x;
  tiles_y_ = max_tiles_y;
  // EMVA 1288: photo-electrons are Poisson (variance = mean in e-), read noise adds in
  // quadrature, uniform quantisation adds 1/12 DN^2. In DN^2: (I - black) / gain + offset.
  variance_per_dn_ = 1.0 / config.gain_e_per_dn;
  const double read_dn = config.read_noise_e / config.gain_e_per_dn;
  variance_offset_dn2_ = read_dn * read_dn + 1.0 / 12.0;
}

int Centroider::check_frame(const frame::FrameView& frame) const {
  if (frame.pixels == nullptr || frame.width <= 0 || frame.height <= 0) return -EINVAL;
  if (frame.width > max_width_ || frame.height > max_height_) return -EINVAL;
  if (frame.format == frame::PixelFormat::kMono8) {
    if (frame.bits_per_pixel < 1 || frame.bits_per_pixel > 8) return -EINVAL;
    if (frame.stride_bytes < frame.width) return -EINVAL;
  } else if (frame.format == frame::PixelFormat::kMono16) {
    if (frame.bits_per_pixel < 9 || frame.bits_per_pixel > 16) return -EINVAL;
    if (frame.stride_bytes < 2 * frame.width || frame.stride_bytes % 2 != 0) return -EINVAL;
    if (reinterpret_cast<std::uintptr_t>(frame.pixels) % 2 != 0) return -EINVAL;
  } else {
    return -EINVAL;
  }
  return 0;
}

int Centroider::process(const frame::FrameView& frame, std::span<Blob> out) {
  ++stats_.frames;
  if (check_frame(frame) != 0) {
    ++stats_.frames_refused;
    return -EINVAL;
  }
  regions_[0] = Region{0, 0, frame.width, frame.height, 0};
  region_count_ = 1;
  return process_regions(frame, true, out);
}

int Centroider::process(const frame::FrameView& frame, std::span<const Roi> rois,
                        std::span<Blob> out) {
  ++stats_.frames;
  if (check_frame(frame) != 0 || rois.size() > regions_.size()) {
    ++stats_.frames_refused;
    return -EINVAL;
  }
  region_count_ = 0;
  for (const Roi& roi : rois) {
    const int x0 = std::clamp(roi.x, 0, frame.width);
    const int y0 = std::clamp(roi.y, 0, frame.height);
    // 64-bit sums: an ROI near INT_MAX must not overflow.
    const int x1 =
        static_cast<int>(std::clamp<std::int64_t>(std::int64_t{roi.x} + roi.width, 0, frame.width));
    const int y1 = static_cast<int>(
        std::clamp<std::int64_t>(std::int64_t{roi.y} + roi.height, 0, frame.height));
    if (x1 <= x0 || y1 <= y0) continue;
    regions_[region_count_++] = Region{x0, y0, x1, y1, 0};
  }
  return process_regions(frame, false, out);
}

int Centroider::process_regions(const frame::FrameView& frame, bool whole_frame,
                                std::span<Blob> out) {
  const bool mono16 = frame.format == frame::PixelFormat::kMono16;
  max_value_ = (1 << frame.bits_per_pixel) - 1;
  saturation_dn_ =
      config_.saturation_dn > 0 ? std::min(config_.saturation_dn, max_value_) : max_value_;
  frame_width_ = frame.width;
  frame_height_ = frame.height;
  tiles_x_ = (frame.width + tile_px_ - 1) / tile_px_;
  tiles_y_ = (frame.height + tile_px_ - 1) / tile_px_;
  if (mono16) {
    estimate_background<std::uint16_t>(frame, whole_frame);
  } else {
    estimate_background<std::uint8_t>(frame, whole_frame);
  }

  run_count_ = 0;
  run_overflow_ = false;
  for (int r = 0; r < region_count_; ++r) {
    const int rc = mono16 ? scan_region<std::uint16_t>(frame, r, !whole_frame)
                          : scan_region<std::uint8_t>(frame, r, !whole_frame);
    if (rc != 0) {
      ++stats_.run_overflows;
      ++stats_.frames_refused;
      stats_.last_runs = run_count_;
      stats_.last_candidates = 0;
      return rc;
    }
  }
  stats_.last_runs = run_count_;

  if (mono16) {
    accumulate<std::uint16_t>(frame);
  } else {
    accumulate<std::uint8_t>(frame);
  }
  stats_.last_candidates = candidate_count_;

  // Keep the components big enough to be marks; if the output cannot take them all, keep the
  // brightest (threshold flux) so the loss is the faintest marks, and say so in the counters.
  int kept = 0;
  for (int i = 0; i < candidate_count_; ++i) {
    const Candidate& c = candidates_[i];
    if (c.area < config_.min_area_px || !(c.sw > 0)) {
      ++stats_.blobs_too_small;
      continue;
    }
    selected_[kept++] = i;
  }
  const int capacity = static_cast<int>(std::min<size_t>(out.size(), selected_.size()));
  if (kept > capacity) {
    stats_.blobs_truncated += static_cast<std::uint64_t>(kept - capacity);
    auto brighter = [this](std::int32_t a, std::int32_t b) {
      return candidates_[a].sw > candidates_[b].sw;
    };
    std::nth_element(selected_.begin(), selected_.begin() + capacity, selected_.begin() + kept,
                     brighter);
    kept = capacity;
    std::sort(selected_.begin(), selected_.begin() + kept);  // back to raster order
  }
  selected_count_ = kept;

  int written = 0;
  for (int k = 0; k < kept; ++k) {
    const bool ok = mono16 ? measure<std::uint16_t>(frame, selected_[k], out[written])
                           : measure<std::uint8_t>(frame, selected_[k], out[written]);
    if (ok) ++written;
  }
  return written;
}

namespace {
// Tile interval and interpolation weight along one axis: tile centres sit at the middle of
// each tile's pixels (the last tile may be partial); beyond the outer centres the level is
// extrapolated linearly for up to half a tile, so gradients hold up to the frame edge.
struct AxisWeight {
  int t0, t1;
  double f;
};
AxisWeight axis_weight(double x, int tile, int tiles, int extent) {
  if (tiles < 2) return {0, 0, 0.0};
  auto centre = [&](int t) { return 0.5 * (t * tile + std::min((t + 1) * tile, extent) - 1); };
  const int t0 = std::clamp(static_cast<int>(std::floor((x + 0.5) / tile - 0.5)), 0, tiles - 2);
  const double c0 = centre(t0), c1 = centre(t0 + 1);
  return {t0, t0 + 1, std::clamp((x - c0) / (c1 - c0), -0.75, 1.75)};
}
}  // namespace

template <typename Pixel>
void Centroider::estimate_background(const frame::FrameView& frame, bool whole_frame) {
  // A full frame estimates every tile. ROI mode estimates only the tiles its regions read: the
  // tiles under them (thresholds, a component's level) and the neighbours the bilinear
  // interpolation of background_at() uses. Each of those tiles gets the same samples, so the
  // same level, as in a full frame; the others are neither read nor written.
  const int n_tiles = tiles_x_ * tiles_y_;
  int n_estimated = 0;
  if (whole_frame) {
    for (int ty = 0; ty < tiles_y_; ++ty)
      for (int tx = 0; tx < tiles_x_; ++tx)
        estimate_tile<Pixel>(frame, tx, ty);
    std::copy(tile_background_.begin(), tile_background_.begin() + n_tiles, sorted_tiles_.begin());
    n_estimated = n_tiles;
  } else {
    std::fill(tile_wanted_.begin(), tile_wanted_.begin() + n_tiles, std::uint8_t{0});
    for (int r = 0; r < region_count_; ++r)
      mark_region_tiles(regions_[r]);
    prefetch_first_rows<Pixel>(frame);
    for (int t = 0; t < n_tiles; ++t) {
      if (tile_wanted_[t] == 0) continue;
      estimate_tile<Pixel>(frame, t % tiles_x_, t / tiles_x_);
      sorted_tiles_[n_estimated++] = tile_background_[t];
    }
    if (n_estimated == 0) return;  // no region: nothing is measured, the levels stay
  }
  std::nth_element(sorted_tiles_.begin(), sorted_tiles_.begin() + n_estimated / 2,
                   sorted_tiles_.begin() + n_estimated);
  stats_.last_background_dn = sorted_tiles_[n_estimated / 2];
  stats_.last_noise_dn =
      static_cast<float>(std::sqrt(pixel_variance_dn2(stats_.last_background_dn)));
  stats_.last_threshold_dn =
      config_.threshold_dn > 0 ? static_cast<float>(config_.threshold_dn)
                               : static_cast<float>(config_.threshold_sigma) * stats_.last_noise_dn;
}

void Centroider::mark_region_tiles(const Region& region) {
  // Along one axis: the tiles holding pixels lo..hi, and those background_at() interpolates
  // between for a point in that span (axis_weight() is monotonic in the position).
  auto span = [this](int lo, int hi, int tiles, int extent, int& first, int& last) {
    const AxisWeight a = axis_weight(lo, tile_px_, tiles, extent);
    const AxisWeight b = axis_weight(hi, tile_px_, tiles, extent);
    first = std::min(lo / tile_px_, a.t0);
    last = std::max(hi / tile_px_, b.t1);
  };
  int tx0 = 0, tx1 = 0, ty0 = 0, ty1 = 0;
  span(region.x0, region.x1 - 1, tiles_x_, frame_width_, tx0, tx1);
  span(region.y0, region.y1 - 1, tiles_y_, frame_height_, ty0, ty1);
  for (int ty = ty0; ty <= ty1; ++ty)
    for (int tx = tx0; tx <= tx1; ++tx)
      tile_wanted_[ty * tiles_x_ + tx] = 1;
}

template <typename Pixel>
void Centroider::prefetch_first_rows(const frame::FrameView& frame) const {
  // ROI mode reads a few cache lines here and there in a frame that is not in the cache: the
  // tiles' sample rows and the ROIs' rows. Read one after the other, each costs a memory
  // latency. So before reading any, ask for every sample row of the tiles to be estimated and
  // the first rows of every ROI (scan_region() asks for the later ones ahead of its scan).
  const int row_step = config_.background_row_step_px;
  const int step = config_.background_column_step_px;
  for (int t = 0; t < tiles_x_ * tiles_y_; ++t) {
    if (tile_wanted_[t] == 0) continue;
    const int y0 = t / tiles_x_ * tile_px_, x0 = t % tiles_x_ * tile_px_;
    const int y1 = std::min(y0 + tile_px_, frame.height);
    const int x1 = std::min(x0 + tile_px_, frame.width);
    const int ys = y0 + std::min(row_step / 2, (y1 - y0 - 1) / 2);
    const int xs = x0 + std::min(step / 2, (x1 - x0 - 1) / 2);
    for (int y = ys; y < y1; y += row_step)
      prefetch_span(row_pointer<Pixel>(frame, y) + xs, (x1 - xs) * static_cast<int>(sizeof(Pixel)));
  }
  for (int r = 0; r < region_count_; ++r) {
    const Region& region = regions_[r];
    const int bytes = (region.x1 - region.x0) * static_cast<int>(sizeof(Pixel));
    for (int y = region.y0; y < std::min(region.y0 + kPrefetchRows, region.y1); ++y)
      prefetch_span(row_pointer<Pixel>(frame, y) + region.x0, bytes);
  }
}

template <typename Pixel>
void Centroider::estimate_tile(const frame::FrameView& frame, int tx, int ty) {
  // Few rows, many pixels per row: a sampled row costs its cache lines once, so this reads
  // 1/row_step of the frame's memory for the same number of samples as a square grid.
  const int row_step = config_.background_row_step_px;
  const int step = config_.background_column_step_px;
  const double read_dn = config_.read_noise_e / config_.gain_e_per_dn;
  const int y0 = ty * tile_px_;
  const int y1 = std::min(y0 + tile_px_, frame.height);
  const int ys = y0 + std::min(row_step / 2, (y1 - y0 - 1) / 2);
  const int x0 = tx * tile_px_;
  const int x1 = std::min(x0 + tile_px_, frame.width);
  const int xs = x0 + std::min(step / 2, (x1 - x0 - 1) / 2);
  // Median of a sparse grid (robust against the few mark pixels), then the mean of the
  // samples within +-3 sigma of it: the median of integer DN is only good to ~0.5 DN.
  double median = 0, clipped_sum = 0;
  int clipped_n = 0;
  if constexpr (sizeof(Pixel) == 1) {
    std::array<std::uint32_t, 256> histogram{};
    int n = 0;
    for (int y = ys; y < y1; y += row_step) {
      const Pixel* row = row_pointer<Pixel>(frame, y);
      for (int x = xs; x < x1; x += step)
        ++histogram[row[x]];
      n += (x1 - xs + step - 1) / step;
    }
    int cumulative = 0, m = 0;
    while (m < 255 && 2 * (cumulative + static_cast<int>(histogram[m])) < n + 1) {
      cumulative += static_cast<int>(histogram[m]);
      ++m;
    }
    median = m;
    const double half = std::max(1.0, 3.0 * std::sqrt(pixel_variance_dn2(median)));
    const int lo = std::max(0, static_cast<int>(std::ceil(median - half)));
    const int hi = std::min(255, static_cast<int>(std::floor(median + half)));
    for (int v = lo; v <= hi; ++v) {
      clipped_sum += static_cast<double>(v) * histogram[v];
      clipped_n += static_cast<int>(histogram[v]);
    }
  } else {
    int n = 0;
    for (int y = ys; y < y1; y += row_step) {
      const Pixel* row = row_pointer<Pixel>(frame, y);
      for (int x = xs; x < x1; x += step)
        samples_[n++] = row[x];
    }
    std::nth_element(samples_.begin(), samples_.begin() + n / 2, samples_.begin() + n);
    median = samples_[n / 2];
    const double half = std::max(1.0, 3.0 * std::sqrt(pixel_variance_dn2(median)));
    for (int i = 0; i < n; ++i) {
      if (std::abs(samples_[i] - median) <= half) {
        clipped_sum += samples_[i];
        ++clipped_n;
      }
    }
  }
  const double background = clipped_n > 0 ? clipped_sum / clipped_n : median;
  double delta = config_.threshold_dn;
  if (delta <= 0) {
    const double signal_e =
        std::max(background - config_.black_level_dn, 0.0) * config_.gain_e_per_dn;
    const double noise_dn = std::sqrt(signal_e / (config_.gain_e_per_dn * config_.gain_e_per_dn) +
                                      read_dn * read_dn + 1.0 / 12.0);
    delta = config_.threshold_sigma * noise_dn;
  }
  const int t = ty * tiles_x_ + tx;
  tile_background_[t] = static_cast<float>(background);
  tile_threshold_[t] = static_cast<std::int32_t>(
      std::clamp(std::floor(background + delta), 0.0, static_cast<double>(max_value_)));
}

int Centroider::find(int run) const {
  while (parent_[run] != run) {
    parent_[run] = parent_[parent_[run]];  // path halving
    run = parent_[run];
  }
  return run;
}

void Centroider::unite(int a, int b) {
  a = find(a);
  b = find(b);
  if (a == b) return;
  // The smaller index stays the root, so a component's root is its first run in raster order.
  if (a < b) {
    parent_[b] = a;
  } else {
    parent_[a] = b;
  }
}

template <typename Pixel>
int Centroider::scan_region(const frame::FrameView& frame, int region_index, bool prefetch) {
  Region& region = regions_[region_index];
  const int max_runs = static_cast<int>(runs_.size());
  int prev_begin = run_count_, prev_end = run_count_;
  int current_tile_row = -1;
  for (int y = region.y0; y < region.y1; ++y) {
    const int tile_row = y / tile_px_;
    if (tile_row != current_tile_row) {
      current_tile_row = tile_row;
      // Only the region's chunks: in ROI mode the other tiles are not estimated.
      for (int c = region.x0 / kChunk; c <= (region.x1 - 1) / kChunk; ++c)
        row_threshold_[c] = tile_threshold_[tile_row * tiles_x_ + chunk_tile_[c]];
    }
    const Pixel* row = row_pointer<Pixel>(frame, y);
    if (prefetch && y + kPrefetchRows < region.y1) {
      // A window row is one or two cache lines a stride apart, not a stream the hardware
      // prefetcher follows at once: ask for the row kPrefetchRows ahead. (Not in a full frame:
      // there the hardware streams, and the prefetches only cost.)
      prefetch_span(row_pointer<Pixel>(frame, y + kPrefetchRows) + region.x0,
                    (region.x1 - region.x0) * static_cast<int>(sizeof(Pixel)));
    }
    const int row_begin = run_count_;
    bool in_run = false;
    int start = 0;
    int x = region.x0;
    auto emit = [&](int x_last) {
      if (run_count_ >= max_runs) {
        run_overflow_ = true;
        return;
      }
      runs_[run_count_] = Run{y, start, x_last};
      parent_[run_count_] = run_count_;
      ++run_count_;
    };
    auto scalar = [&](int x_end, Pixel level) {
      for (; x < x_end; ++x) {
        const bool on = row[x] > level;
        if (on == in_run) continue;
        if (on) {
          start = x;
        } else {
          emit(x - 1);
        }
        in_run = on;
      }
    };
    while (x < region.x1) {
      const int chunk = x / kChunk;
      const int chunk_end = std::min((chunk + 1) * kChunk, region.x1);
      const Pixel level = static_cast<Pixel>(row_threshold_[chunk]);
      if (x == chunk * kChunk && chunk_end - x == kChunk &&
          !any_above<Pixel, kChunk>(row + x, level)) {
        // The common case of a full frame: the whole chunk is background.
        if (in_run) {
          emit(x - 1);
          in_run = false;
        }
        x = chunk_end;
        continue;
      }
      // A chunk with foreground, or the part of one inside an ROI (window rows rarely start on
      // a chunk): 64 then 16 bytes at a time wherever they fit (unaligned loads), one pixel at
      // a time only where a group has a pixel above the level and for the last few pixels.
      constexpr int kBlock = 4 * kLanes<Pixel>;
      while (x + kBlock <= chunk_end && !any_above<Pixel, kBlock>(row + x, level)) {
        if (in_run) {
          emit(x - 1);
          in_run = false;
        }
        x += kBlock;
      }
      while (x + kLanes<Pixel> <= chunk_end) {
        if (any_above<Pixel, kLanes<Pixel>>(row + x, level)) {
          scalar(x + kLanes<Pixel>, level);
          continue;
        }
        if (in_run) {
          emit(x - 1);
          in_run = false;
        }
        x += kLanes<Pixel>;
      }
      scalar(chunk_end, level);
    }
    if (in_run) emit(region.x1 - 1);
    if (run_overflow_) return -EOVERFLOW;
    const int row_end = run_count_;
    // 8-connectivity with the previous row: runs overlap when they come within one column.
    int i = prev_begin;
    for (int j = row_begin; j < row_end; ++j) {
      while (i < prev_end && runs_[i].x1 + 1 < runs_[j].x0)
        ++i;
      for (int k = i; k < prev_end && runs_[k].x0 <= runs_[j].x1 + 1; ++k)
        unite(k, j);
    }
    prev_begin = row_begin;
    prev_end = row_end;
  }
  region.run_end = run_count_;
  return 0;
}

template <typename Pixel>
void Centroider::accumulate(const frame::FrameView& frame) {
  candidate_count_ = 0;
  int region = 0;
  const int max_candidates = static_cast<int>(candidates_.size());
  for (int r = 0; r < run_count_; ++r) {
    while (region < region_count_ - 1 && r >= regions_[region].run_end)
      ++region;
    const Run& run = runs_[r];
    const int root = find(r);
    if (root == r) {
      if (candidate_count_ >= max_candidates) {
        label_[r] = -1;
        ++stats_.candidates_dropped;
        continue;
      }
      label_[r] = candidate_count_;
      Candidate& c = candidates_[candidate_count_++];
      c = Candidate{};
      c.ref_x = run.x0;
      c.ref_y = run.y;
      c.xmin = run.x0;
      c.xmax = run.x1;
      c.ymin = c.ymax = run.y;
      c.peak = -1;
      c.region = region;
      c.background = tile_background_[(run.y / tile_px_) * tiles_x_ + run.x0 / tile_px_];
    } else {
      label_[r] = label_[root];
      if (label_[r] < 0) continue;
    }
    Candidate& c = candidates_[label_[r]];
    const Pixel* row = row_pointer<Pixel>(frame, run.y);
    const double b = c.background;
    const double dy = run.y - c.ref_y;
    // Integer moments of the readings about the run's first pixel (i = x - x0), then the
    // background-subtracted and variance moments about ref_x from them: the per-pixel work is
    // three integer multiply-adds. (v = (value - black) k + offset while value >= black: the
    // noise model is linear in the reading; a run dipping below the black level, not a mark's
    // in practice, takes the per-pixel path.)
    const int n = run.x1 - run.x0 + 1;
    const Pixel* p = row + run.x0;
    std::int64_t s0 = 0, s1 = 0, s2 = 0;
    int lowest = max_value_;
    for (int i = 0; i < n; ++i) {
      const int value = p[i];
      s0 += value;
      s1 += std::int64_t{value} * i;
      s2 += std::int64_t{value} * i * i;
      lowest = std::min(lowest, value);
      if (value > c.peak) {
        c.peak = value;
        c.peak_x = run.x0 + i;
        c.peak_y = run.y;
      }
      if (value >= saturation_dn_) ++c.saturated;
    }
    // Sums of 1, i, i^2 over the run, and the moments about ref_x: dx = i + o.
    const double n0 = n, n1 = 0.5 * n * (n - 1.0), n2 = (n - 1.0) * n * (2.0 * n - 1.0) / 6.0;
    const double o = run.x0 - c.ref_x;
    auto about_ref = [o](double m0, double m1, double m2, double& r0, double& r1, double& r2) {
      r0 = m0;
      r1 = m1 + o * m0;
      r2 = m2 + 2.0 * o * m1 + o * o * m0;
    };
    double sw = 0, swx = 0, swxx = 0, sv = 0, svx = 0, svxx = 0;
    about_ref(double(s0) - b * n0, double(s1) - b * n1, double(s2) - b * n2, sw, swx, swxx);
    if (lowest >= config_.black_level_dn) {
      const double k = variance_per_dn_, black = config_.black_level_dn;
      const double off = variance_offset_dn2_;
      about_ref(k * (double(s0) - black * n0) + off * n0, k * (double(s1) - black * n1) + off * n1,
                k * (double(s2) - black * n2) + off * n2, sv, svx, svxx);
    } else {
      for (int i = 0; i < n; ++i) {
        const double v = pixel_variance_dn2(p[i]);
        const double dx = i + o;
        sv += v;
        svx += v * dx;
        svxx += v * dx * dx;
      }
    }
    c.sw += sw;
    c.swx += swx;
    c.swy += sw * dy;
    c.swxx += swxx;
    c.swyy += sw * dy * dy;
    c.swxy += swx * dy;
    c.sv += sv;
    c.svx += svx;
    c.svy += sv * dy;
    c.svxx += svxx;
    c.svyy += sv * dy * dy;
    c.area += run.x1 - run.x0 + 1;
    c.xmin = std::min(c.xmin, run.x0);
    c.xmax = std::max(c.xmax, run.x1);
    c.ymax = std::max(c.ymax, run.y);
  }
}

float Centroider::background_at(double x, double y) const {
  const AxisWeight u = axis_weight(x, tile_px_, tiles_x_, frame_width_);
  const AxisWeight v = axis_weight(y, tile_px_, tiles_y_, frame_height_);
  const auto at = [this](int tu, int tv) { return tile_background_[tv * tiles_x_ + tu]; };
  return static_cast<float>((1 - v.f) * ((1 - u.f) * at(u.t0, v.t0) + u.f * at(u.t1, v.t0)) +
                            v.f * ((1 - u.f) * at(u.t0, v.t1) + u.f * at(u.t1, v.t1)));
}

namespace {
/// Offsets along one axis of the pixels on the line from a peak to a point `delta` away, at
/// steps 1, 2, ... of `steps` (>= |delta|): round(delta s / steps), half away from zero, as
/// lround(double(delta) * s / steps) gives it, but by Bresenham's increments (no division or
/// library call per step).
class LineAxis {
 public:
  LineAxis(int delta, int steps)
      : sign_(delta < 0 ? -1 : 1), increment_(2 * std::abs(delta)), period_(2 * steps) {
    const int first = increment_ + steps;  // 2 |delta| s + steps at s = 1
    quotient_ = first / period_;
    remainder_ = first % period_;
  }
  int offset() const { return sign_ * quotient_; }
  void next() {
    remainder_ += increment_;  // increment_ <= period_: at most one carry
    if (remainder_ >= period_) {
      remainder_ -= period_;
      ++quotient_;
    }
  }

 private:
  int sign_, increment_, period_, quotient_ = 0, remainder_ = 0;
};
}  // namespace

template <typename Pixel>
bool Centroider::has_separate_maxima(const frame::FrameView& frame, const Candidate& c) const {
  const Region& region = regions_[c.region];
  const double b = c.background;
  const double main_height = c.peak - b;
  const double min_height =
      std::max(config_.merge_peak_fraction * main_height, 0.5 * stats_.last_threshold_dn);
  // The lowest reading with value - b >= min_height, exactly (the test per pixel in integers);
  // -1 passes every reading, 65536 none.
  int min_value = static_cast<int>(std::clamp(std::ceil(b + min_height), -1.0, 65536.0));
  while (min_value > -1 && min_value - 1 - b >= min_height)
    --min_value;
  while (min_value < 65536 && min_value - b < min_height)
    ++min_value;
  // A pixel is a local maximum when no pixel of its 3x3 neighbourhood (inside the region) is
  // brighter: with column_max_[x] the maximum of rows y-1..y+1 in column x, when it is not below
  // the maximum of column_max_ over x-1..x+1.
  const int cx0 = std::max(c.xmin - 1, region.x0), cx1 = std::min(c.xmax + 1, region.x1 - 1);
  std::uint16_t* column_max = column_max_.data();
  for (int y = c.ymin; y <= c.ymax; ++y) {
    const Pixel* row = row_pointer<Pixel>(frame, y);
    const Pixel* above = row_pointer<Pixel>(frame, std::max(y - 1, region.y0));
    const Pixel* below = row_pointer<Pixel>(frame, std::min(y + 1, region.y1 - 1));
    for (int x = cx0; x <= cx1; ++x)
      column_max[x - cx0] = std::max({above[x], row[x], below[x]});
    for (int x = c.xmin; x <= c.xmax; ++x) {
      const int value = row[x];
      if (value < min_value) continue;
      const int around = std::max({column_max[std::max(x - 1, cx0) - cx0], column_max[x - cx0],
                                   column_max[std::min(x + 1, cx1) - cx0]});
      if (around > value) continue;
      const int steps = std::max(std::abs(x - c.peak_x), std::abs(y - c.peak_y));
      if (steps < 2) continue;
      // A real second mark has a dip between it and the main peak; noise on a flat top does not.
      int dip = value;
      LineAxis along_x(x - c.peak_x, steps), along_y(y - c.peak_y, steps);
      for (int s = 1; s < steps; ++s, along_x.next(), along_y.next())
        dip = std::min<int>(
            dip,
            row_pointer<Pixel>(frame, c.peak_y + along_y.offset())[c.peak_x + along_x.offset()]);
      const double height = value - b;
      const double dip_height = dip - b;
      if (dip_height < (1.0 - config_.merge_dip_fraction) * height &&
          height - dip_height > 3.0 * std::sqrt(pixel_variance_dn2(value)))
        return true;
    }
  }
  return false;
}

template <typename Pixel>
bool Centroider::measure(const frame::FrameView& frame, int candidate_index, Blob& blob) {
  const Candidate& c = candidates_[candidate_index];
  const Region& region = regions_[c.region];
  const double mx = c.swx / c.sw, my = c.swy / c.sw;
  const double mxx = std::max(c.swxx / c.sw - mx * mx, 0.0);
  const double myy = std::max(c.swyy / c.sw - my * my, 0.0);
  const double mxy = c.swxy / c.sw - mx * my;
  const double half_trace = 0.5 * (mxx + myy);
  const double spread = std::sqrt(0.25 * (mxx - myy) * (mxx - myy) + mxy * mxy);
  const double major = half_trace + spread, minor = half_trace - spread;
  const float axis_ratio =
      minor > 1e-12 ? static_cast<float>(std::sqrt(major / minor)) : (major > 0 ? 99.0f : 1.0f);

  blob = Blob{};
  blob.x_px = c.ref_x + mx;
  blob.y_px = c.ref_y + my;
  blob.peak_dn = static_cast<float>(c.peak - c.background);
  blob.flux_dn = static_cast<float>(c.sw);
  blob.area_px = static_cast<float>(c.area);
  blob.diameter_px = static_cast<float>(std::sqrt(4.0 * c.area / std::numbers::pi));
  blob.axis_ratio = std::min(axis_ratio, 99.0f);
  blob.background_dn = c.background;
  if (c.saturated > 0) blob.flags |= blob_flags::kSaturated;
  if (c.xmin == region.x0 || c.ymin == region.y0 || c.xmax == region.x1 - 1 ||
      c.ymax == region.y1 - 1)
    blob.flags |= blob_flags::kBorder;
  if (axis_ratio > config_.max_axis_ratio) blob.flags |= blob_flags::kElongated;
  if (c.area > config_.max_area_px || has_separate_maxima<Pixel>(frame, c))
    blob.flags |= blob_flags::kMerged;

  if (config_.refine && refine<Pixel>(frame, candidate_index, blob)) return true;
  if (config_.refine) ++stats_.refine_fallbacks;
  // Threshold moments: var(x) = sum v_i (x_i - x)^2 / (sum w_i)^2 over the thresholded pixels.
  const double var_x = (c.svxx - 2 * mx * c.svx + mx * mx * c.sv) / (c.sw * c.sw);
  const double var_y = (c.svyy - 2 * my * c.svy + my * my * c.sv) / (c.sw * c.sw);
  blob.sigma_px = std::sqrt(std::max(0.5 * (var_x + var_y), 0.0));
  return true;
}

bool Centroider::windowed_variance(double sigma, float background, double xc, double yc,
                                   double& var_x, double& var_y, double& flux) {
  // Standard deviation by linearising the fixed-point equation g(xc) = sum w (x - xc) p = 0:
  //   var(xc) = sum w^2 (x - xc)^2 var_i / D^2,  D = -dg/dxc = sum w p (1 - (x - xc)^2 / s_w^2).
  gaussian_window(patch_x0_, patch_w_, xc, sigma, dx_.data(), wx_.data());
  gaussian_window(patch_y0_, patch_h_, yc, sigma, dy_.data(), wy_.data());
  const int pw = patch_w_, ph = patch_h_;
  double s = 0, qx = 0, qy = 0, vx = 0, vy = 0;
  flux = 0;
  for (int j = 0; j < ph; ++j) {
    const float* p = &patch_[static_cast<size_t>(j) * pw];
    const float* keep = &patch_keep_[static_cast<size_t>(j) * pw];
    const float* wx = wx_.data();
    const float* dx = dx_.data();
    // Per-pixel variance from the noise model, evaluated on the pixel's own reading.
    const float above_black = background - static_cast<float>(config_.black_level_dn);
    const float per_dn = static_cast<float>(variance_per_dn_);
    const float offset = static_cast<float>(variance_offset_dn2_);
    float r0 = 0, r2 = 0, a0 = 0, a2 = 0, f = 0;
#pragma omp simd reduction(+ : r0, r2, a0, a2, f)
    for (int i = 0; i < pw; ++i) {
      const float wp = wx[i] * p[i];
      const float var = keep[i] * (std::max(p[i] + above_black, 0.0f) * per_dn + offset);
      const float w2v = wx[i] * wx[i] * var;
      r0 += wp;
      r2 += wp * dx[i] * dx[i];
      a0 += w2v;
      a2 += w2v * dx[i] * dx[i];
      f += p[i];
    }
    flux += f;
    const double wy2 = wy_[j] * wy_[j];
    s += wy_[j] * r0;
    qx += wy_[j] * r2;
    qy += wy_[j] * dy_[j] * dy_[j] * r0;
    vx += wy2 * a2;
    vy += wy2 * dy_[j] * dy_[j] * a0;
  }
  const double inv_s2 = 1.0 / (sigma * sigma);
  const double dxd = s - qx * inv_s2, dyd = s - qy * inv_s2;
  if (!(dxd > 0) || !(dyd > 0)) return false;
  var_x = vx / (dxd * dxd);
  var_y = vy / (dyd * dyd);
  return true;
}

namespace {
struct MlTerms {
  float v0, ka, c_var, above_black, per_dn, offset;
};
struct MlSums {
  float gx = 0, gy = 0, ddx = 0, ddy = 0, vx = 0, vy = 0, gp = 0, total = 0;
};
/// One pass of the ML estimating equation over the flattened patch (photon_weighted_step()):
/// the score, its derivative and the template fit, and with kLast the variance and flux (only
/// the last pass's are reported, so the earlier passes skip them).
template <bool kLast>
MlSums ml_sums(int n, const float* p, const float* keep, const float* fdx, const float* fdy,
               const float* fg, const MlTerms& t) {
  float gx = 0, gy = 0, ddx = 0, ddy = 0, vx = 0, vy = 0, gp = 0, total = 0;
  if constexpr (kLast) {
#pragma omp simd reduction(+ : gx, gy, ddx, ddy, vx, vy, gp, total)
    for (int k = 0; k < n; ++k) {
      const float g = fg[k];
      const float inv = 1.0f / (t.v0 + t.ka * g);
      const float w = g * inv;
      const float pw = p[k] * w;
      const float c = t.c_var * inv;  // v0 / (s^2 (v0 + k A g))
      const float var = keep[k] * (std::max(p[k] + t.above_black, 0.0f) * t.per_dn + t.offset);
      const float w2v = w * w * var;
      const float dx2 = fdx[k] * fdx[k], dy2 = fdy[k] * fdy[k];
      gx += pw * fdx[k];
      gy += pw * fdy[k];
      ddx += pw * (1.0f - dx2 * c);
      ddy += pw * (1.0f - dy2 * c);
      vx += w2v * dx2;
      vy += w2v * dy2;
      gp += g * p[k];
      total += p[k];
    }
  } else {
#pragma omp simd reduction(+ : gx, gy, ddx, ddy, gp)
    for (int k = 0; k < n; ++k) {
      const float g = fg[k];
      const float inv = 1.0f / (t.v0 + t.ka * g);
      const float pw = p[k] * (g * inv);
      const float c = t.c_var * inv;
      gx += pw * fdx[k];
      gy += pw * fdy[k];
      ddx += pw * (1.0f - fdx[k] * fdx[k] * c);
      ddy += pw * (1.0f - fdy[k] * fdy[k] * c);
      gp += g * p[k];
    }
  }
  return {gx, gy, ddx, ddy, vx, vy, gp, total};
}
}  // namespace

bool Centroider::photon_weighted_step(double sigma, float background, double amplitude, int steps,
                                      double& xc, double& yc, double& var_x, double& var_y,
                                      double& flux) {
  // Maximum-likelihood estimating equation for a Gaussian spot g of amplitude A under the
  // Poisson + read noise model (the score of x: sum (I_i - mu_i) dmu_i/dx / var_i = 0, e.g.
  // Smith et al. 2010, Nat. Methods 7:373; Mortensen et al. 2010, Nat. Methods 7:377): by the
  // spot's symmetry it reduces to sum p_i (x_i - xc) W_i = 0 with the weight
  //   W = g / (v0 + k A g),   v0 = background variance [DN^2], k = 1 / gain [DN^2 / DN],
  // i.e. the Gaussian window flattened where photon noise dominates. Two Newton steps from the
  // windowed solution (already within the noise of the ML solution). A = sum g p / sum g^2
  // (least squares on the template), from the previous pass.
  const float above_black = background - static_cast<float>(config_.black_level_dn);
  const float per_dn = static_cast<float>(variance_per_dn_);
  const float offset = static_cast<float>(variance_offset_dn2_);
  const float v0 = std::max(above_black, 0.0f) * per_dn + offset;
  const double inv_s2 = 1.0 / (sigma * sigma);
  double new_x = xc, new_y = yc, new_var_x = 0, new_var_y = 0, sum_gp = -1;
  for (int pass = 0; pass < steps; ++pass) {
    gaussian_window(patch_x0_, patch_w_, new_x, sigma, dx_.data(), wx_.data());
    gaussian_window(patch_y0_, patch_h_, new_y, sigma, dy_.data(), wy_.data());
    double sgx2 = 0, sgy2 = 0;
    for (int i = 0; i < patch_w_; ++i)
      sgx2 += double(wx_[i]) * wx_[i];
    for (int j = 0; j < patch_h_; ++j)
      sgy2 += double(wy_[j]) * wy_[j];
    if (sum_gp >= 0) amplitude = sum_gp / (sgx2 * sgy2);
    const float ka = static_cast<float>(std::max(amplitude, 0.0) * per_dn);
    const float c_var = static_cast<float>(v0 * inv_s2);
    // The weight is not separable: flatten the patch so that one SIMD loop covers all of it
    // (per-row loops of ~11 pixels would spend their time in scalar tails and reductions).
    // (Row by row through restrict pointers, so that the copy vectorises too: written through
    // the vectors it was a scalar loop of three stores a pixel, 40 % of this function's time.)
    const int n = patch_w_ * patch_h_;
    const float* __restrict row_dx = dx_.data();
    const float* __restrict row_g = wx_.data();
    for (int j = 0; j < patch_h_; ++j) {
      const size_t row_start = static_cast<size_t>(j) * patch_w_;
      float* __restrict out_dx = flat_dx_.data() + row_start;
      float* __restrict out_dy = flat_dy_.data() + row_start;
      float* __restrict out_g = flat_g_.data() + row_start;
      const float dy = dy_[j], wy = wy_[j];
#pragma omp simd
      for (int i = 0; i < patch_w_; ++i) {
        out_dx[i] = row_dx[i];
        out_dy[i] = dy;
        out_g[i] = row_g[i] * wy;
      }
    }
    const MlTerms terms{v0, ka, c_var, above_black, per_dn, offset};
    const bool last = pass == steps - 1;
    const MlSums sums = last ? ml_sums<true>(n, patch_.data(), patch_keep_.data(), flat_dx_.data(),
                                             flat_dy_.data(), flat_g_.data(), terms)
                             : ml_sums<false>(n, patch_.data(), patch_keep_.data(), flat_dx_.data(),
                                              flat_dy_.data(), flat_g_.data(), terms);
    const float gx = sums.gx, gy = sums.gy, ddx = sums.ddx, ddy = sums.ddy;
    const float vx = sums.vx, vy = sums.vy, gp = sums.gp, total = sums.total;
    if (!(ddx > 0) || !(ddy > 0)) return false;
    const double step_x = double(gx) / ddx, step_y = double(gy) / ddy;
    // A step beyond half a pixel means the template does not fit: keep the windowed solution.
    if (std::abs(step_x) > 0.5 || std::abs(step_y) > 0.5) return false;
    new_x += step_x;
    new_y += step_y;
    new_var_x = double(vx) / (double(ddx) * ddx);
    new_var_y = double(vy) / (double(ddy) * ddy);
    sum_gp = gp;
    flux = total;
  }
  xc = new_x;
  yc = new_y;
  var_x = new_var_x;
  var_y = new_var_y;
  return true;
}

template <typename Pixel>
bool Centroider::refine(const frame::FrameView& frame, int candidate_index, Blob& blob) {
  const Candidate& c = candidates_[candidate_index];
  const Region& region = regions_[c.region];
  const int max_half = config_.max_window_half_px;
  const bool adaptive = config_.window_sigma_px <= 0;
  // Threshold moments underestimate the spot's width (the wings are cut): start wider and let
  // the windowed second moment fix it.
  const double threshold_sigma =
      std::sqrt(std::max(0.5 * ((c.swxx / c.sw - std::pow(c.swx / c.sw, 2)) +
                                (c.swyy / c.sw - std::pow(c.swy / c.sw, 2))),
                         0.0));
  double sigma = adaptive ? std::max(1.0, 1.3 * threshold_sigma) : config_.window_sigma_px;
  double xc = blob.x_px, yc = blob.y_px;
  const double x_start = xc, y_start = yc;
  // Inside the region: in ROI mode only the tiles its points interpolate between are estimated
  // (the threshold centroid is inside anyway; the clamp makes that a guarantee).
  const float background = background_at(std::clamp<double>(xc, region.x0, region.x1 - 1),
                                         std::clamp<double>(yc, region.y0, region.y1 - 1));

  int px0 = 0, py0 = 0, pw = 0, ph = 0, half = 0;
  bool clipped = false;
  // Copies the (2 half + 1)^2 patch around (xc, yc), background-subtracted, with the pixels of
  // other marks' boxes zeroed (and their keep weight in patch_keep_ 0) so a neighbour cannot
  // pull the window.
  auto extract = [&](int new_half) {
    half = new_half;
    const int cx = static_cast<int>(std::lround(xc)), cy = static_cast<int>(std::lround(yc));
    const int x0 = std::max(cx - half, region.x0), x1 = std::min(cx + half, region.x1 - 1);
    const int y0 = std::max(cy - half, region.y0), y1 = std::min(cy + half, region.y1 - 1);
    clipped = x0 != cx - half || x1 != cx + half || y0 != cy - half || y1 != cy + half;
    px0 = patch_x0_ = x0;
    py0 = patch_y0_ = y0;
    pw = patch_w_ = x1 - x0 + 1;
    ph = patch_h_ = y1 - y0 + 1;
    if (pw < 3 || ph < 3) return false;
    const float b = background;
    for (int j = 0; j < ph; ++j) {
      const Pixel* row = row_pointer<Pixel>(frame, py0 + j) + px0;
      float* p = &patch_[static_cast<size_t>(j) * pw];
      float* keep = &patch_keep_[static_cast<size_t>(j) * pw];
#pragma omp simd
      for (int i = 0; i < pw; ++i) {
        p[i] = static_cast<float>(row[i]) - b;
        keep[i] = 1.0f;
      }
    }
    for (int k = 0; k < selected_count_; ++k) {
      const int other_index = selected_[k];
      if (other_index == candidate_index) continue;
      const Candidate& o = candidates_[other_index];
      const int ox0 = std::max(o.xmin - 1, px0), ox1 = std::min(o.xmax + 1, px0 + pw - 1);
      const int oy0 = std::max(o.ymin - 1, py0), oy1 = std::min(o.ymax + 1, py0 + ph - 1);
      for (int y = oy0; y <= oy1; ++y) {
        for (int x = ox0; x <= ox1; ++x) {
          // Never blank our own thresholded box (overlapping boxes of touching marks).
          if (x >= c.xmin && x <= c.xmax && y >= c.ymin && y <= c.ymax) continue;
          patch_[static_cast<size_t>(y - py0) * pw + (x - px0)] = 0;
          patch_keep_[static_cast<size_t>(y - py0) * pw + (x - px0)] = 0;
        }
      }
    }
    return true;
  };
  auto half_for = [max_half, radius = config_.window_radius_sigmas](double s) {
    return std::clamp(static_cast<int>(std::ceil(radius * s)), 3, max_half);
  };
  // Fast start: when the ML stage follows and the window is matched, the windowed iterations
  // only serve to find s_p and get within reach of the ML root. The threshold moments give both
  // directly: for a Gaussian of amplitude A cut at level t (tau = t / A, U = -ln tau) the
  // intensity-weighted second moment per axis is s^2 (1 - (1 + U) tau) / (1 - tau). The
  // threshold centroid is within a few noise sigmas, so two Newton steps of the ML equation
  // converge; if they fail, the windowed route below runs from scratch.
  const bool use_ml_early = config_.photon_weighting && c.saturated == 0 && adaptive;
  if (use_ml_early) {
    const double height = c.peak - c.background;
    const double tau = std::clamp(stats_.last_threshold_dn / std::max(height, 1e-6), 1e-3, 0.9);
    const double factor = (1.0 - (1.0 - std::log(tau)) * tau) / (1.0 - tau);
    const double fast_sigma = std::clamp(threshold_sigma / std::sqrt(factor), 0.5, max_half / 3.5);
    double fx = xc, fy = yc, var_x = 0, var_y = 0, flux = 0;
    if (extract(half_for(fast_sigma)) &&
        photon_weighted_step(fast_sigma, background, height, config_.photon_weighting_steps + 1, fx,
                             fy, var_x, var_y, flux) &&
        std::abs(fx - x_start) <= 0.5 * half && std::abs(fy - y_start) <= 0.5 * half) {
      ++stats_.fast_starts;
      blob.x_px = fx;
      blob.y_px = fy;
      blob.sigma_px = std::sqrt(0.5 * (var_x + var_y));
      blob.flux_dn = static_cast<float>(flux);
      blob.background_dn = background;
      blob.peak_dn = static_cast<float>(c.peak - background);
      if (clipped) blob.flags |= blob_flags::kBorder;
      return true;
    }
  }
  if (!extract(half_for(sigma))) return false;

  auto weights = [&](double s) {
    gaussian_window(px0, pw, xc, s, dx_.data(), wx_.data());
    gaussian_window(py0, ph, yc, s, dy_.data(), wy_.data());
  };

  // Fixed point of sum w_i (x_i - xc) p_i = 0, w = Gaussian window centred on xc (XWIN).
  // For a Gaussian spot of width s_p the raw windowed shift is d s_w^2 / (s_w^2 + s_p^2); the
  // step is scaled by the inverse, estimated from the windowed second moment M2
  // (1/M2 = 1/s_p^2 + 1/s_w^2), i.e. a Newton step (SExtractor uses the matched value 2).
  // With the ML steps to follow, 0.01 px is close enough (a Newton step from there lands within
  // 1e-4 px); alone, the windowed centroid iterates to refine_tolerance_px.
  const bool use_ml = config_.photon_weighting && c.saturated == 0;
  double last_sum = 0;  // sum w p of the last iteration: the ML stage's first amplitude
  int adapt_iterations = adaptive ? 2 : 0;
  auto iterate = [&](double tolerance) {
    for (int it = 0; it < config_.max_refine_iterations + adapt_iterations; ++it) {
      weights(sigma);
      double s = 0, sx = 0, sy = 0, sxx = 0, syy = 0;
      for (int j = 0; j < ph; ++j) {
        const float* p = &patch_[static_cast<size_t>(j) * pw];
        const float* wx = wx_.data();
        const float* dx = dx_.data();
        float r0 = 0, r1 = 0, r2 = 0;  // one row: float SIMD; rows sum in double
#pragma omp simd reduction(+ : r0, r1, r2)
        for (int i = 0; i < pw; ++i) {
          const float wp = wx[i] * p[i];
          r0 += wp;
          r1 += wp * dx[i];
          r2 += wp * dx[i] * dx[i];
        }
        const double wy = wy_[j], dy = dy_[j];
        s += wy * r0;
        sx += wy * r1;
        sy += wy * dy * r0;
        sxx += wy * r2;
        syy += wy * dy * dy * r0;
      }
      if (!(s > 0)) return false;
      last_sum = s;
      const double m2 = 0.5 * (sxx + syy) / s;
      const double s2 = sigma * sigma;
      const double gain = (m2 > 0 && m2 < 0.75 * s2) ? s2 / (s2 - m2) : 4.0;
      const double step_x = gain * sx / s, step_y = gain * sy / s;
      xc += step_x;
      yc += step_y;
      if (std::abs(xc - x_start) > 0.5 * half || std::abs(yc - y_start) > 0.5 * half) return false;
      if (it < adapt_iterations) {
        // Matched window: s_w = s_p (SExtractor's choice, near-optimal for read-noise-limited
        // Gaussian spots). If the window is too narrow to measure s_p, widen it.
        double matched = 2.0 * sigma;
        if (m2 > 0 && m2 < 0.95 * s2) matched = std::sqrt(1.0 / (1.0 / m2 - 1.0 / s2));
        sigma = std::clamp(matched, 0.5, max_half / 3.5);
        if (half_for(sigma) != half && !extract(half_for(sigma))) return false;
        continue;
      }
      if (std::abs(step_x) < tolerance && std::abs(step_y) < tolerance) return true;
    }
    return false;
  };
  if (!iterate(use_ml ? std::max(config_.refine_tolerance_px, 0.01) : config_.refine_tolerance_px))
    return false;
  adapt_iterations = 0;
  double flux = 0, var_x = 0, var_y = 0;
  // First amplitude from the windowed sum: sum g^2 over the lattice is ~ pi s^2.
  if (!use_ml ||
      !photon_weighted_step(sigma, background, last_sum / (std::numbers::pi * sigma * sigma),
                            config_.photon_weighting_steps, xc, yc, var_x, var_y, flux)) {
    if (use_ml && !iterate(config_.refine_tolerance_px)) return false;
    if (!windowed_variance(sigma, background, xc, yc, var_x, var_y, flux)) return false;
  }

  blob.x_px = xc;
  blob.y_px = yc;
  blob.sigma_px = std::sqrt(0.5 * (var_x + var_y));
  blob.flux_dn = static_cast<float>(flux);
  blob.background_dn = background;
  blob.peak_dn = static_cast<float>(c.peak - background);
  if (clipped) blob.flags |= blob_flags::kBorder;
  return true;
}

}  // namespace storetrack::centroid
