// Spot rendering: see render.hpp for the model. The disc (*) blur-segment shape is sampled on a
// grid point-symmetric about the spot centre; each sample's Gaussian PSF is integrated over the
// pixel with erfc, separably, so the image is an exact sum of pixel-integrated Gaussians:
//   image(r, c) = sum_ij W(j, i) * Ey(j, r) * Ex(i, c)  =  (Ey^T W Ex)(r, c).
#include "storetrack/sim/render.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Core>

namespace storetrack::sim {
namespace {

using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using RowMap = Eigen::Map<RowMatrix>;

constexpr double kMinSigmaPx = 0.05;
constexpr double kBoxSigmas = 6.5;  // Gaussian tail beyond 6.5 sigma: < 1e-10 of the flux

double effective_sigma(const Spot& s) {
  return std::max(s.psf_sigma_px, kMinSigmaPx);
}
// Grid spacing of the disc/blur sampling: half a PSF sigma keeps the sum of sampled Gaussians
// indistinguishable from the continuous convolution (sampling error ~exp(-2 pi^2 (sigma/h)^2)).
// The step is 1/m px (m integer) so that grid offsets and pixel edges share one lattice and the
// erfc values can be shared between grid columns (see evaluate()).
int grid_steps_per_px(const Spot& s) {
  return static_cast<int>(std::ceil(1.0 / std::clamp(effective_sigma(s) / 2, 0.05, 0.25)));
}
double grid_step(const Spot& s) {
  return 1.0 / grid_steps_per_px(s);
}
// A point source is modelled as a disc much smaller than the PSF (adds < 0.01 px^2 variance).
double disc_radius(const Spot& s) {
  return std::max(s.disc_diameter_px / 2, 0.75 * grid_step(s));
}

double normal_cdf(double z) {
  return 0.5 * std::erfc(-z * M_SQRT1_2);
}
double normal_pdf(double z) {
  return std::exp(-0.5 * z * z) * (0.5 * M_2_SQRTPI * M_SQRT1_2);
}

void grow(std::vector<double>& v, std::size_t n) {
  if (v.size() < n) v.resize(n);
}

// Fraction of the exposure during which the disc (radius r) covers the point p, the disc centre
// moving along the segment [-L/2, L/2] * u.
double swept_coverage(double px, double py, double r, double ux, double uy, double length) {
  if (length < 1e-9) return (px * px + py * py <= r * r) ? 1.0 : 0.0;
  const double a = px * ux + py * uy;
  const double d2 = px * px + py * py - a * a;
  if (d2 >= r * r) return 0.0;
  const double c = std::sqrt(r * r - d2);
  const double overlap = std::min(a + c, length / 2) - std::max(a - c, -length / 2);
  return std::max(0.0, overlap) / length;
}

// Quantisation of electrons to DN with saturation.
template <typename Pixel>
Pixel to_dn(double electrons, const SensorModel& sensor) {
  const double dn = std::floor(electrons / sensor.gain_e_per_dn + sensor.black_level_dn + 0.5);
  return static_cast<Pixel>(std::clamp(dn, 0.0, static_cast<double>(sensor.full_scale_dn)));
}

// One pixel of the EMVA 1288 sensor: Poisson shot noise on mu electrons, Gaussian read noise,
// quantisation and clipping.
template <typename Pixel>
Pixel draw_dn(double mu, const SensorModel& sensor, std::mt19937_64& rng,
              std::normal_distribution<double>& read_noise) {
  double electrons = 0;
  if (mu > 0) {
    std::poisson_distribution<long> shot(mu);
    electrons = static_cast<double>(shot(rng));
  }
  electrons += sensor.read_noise_e * read_noise(rng);
  return to_dn<Pixel>(electrons, sensor);
}

// Walker/Vose alias table of the exact DN distribution of a pixel with mean mu_e electrons
// (Poisson (*) Gaussian read noise, quantised, clipped): O(1) exact sampling.
void build_dn_alias_table(double mu_e, const SensorModel& sensor, std::vector<double>& alias_prob,
                          std::vector<std::uint32_t>& alias_index) {
  const int levels = sensor.full_scale_dn + 1;
  std::vector<double> pmf(static_cast<std::size_t>(levels), 0.0);
  const double mu = std::max(mu_e, 0.0);
  const double g = sensor.gain_e_per_dn, rn = sensor.read_noise_e;
  const double spread = 12 * std::sqrt(mu) + 10;
  const int n_lo = static_cast<int>(std::max(0.0, std::floor(mu - spread)));
  const int n_hi = static_cast<int>(std::ceil(mu + spread));
  for (int n = n_lo; n <= n_hi; ++n) {
    // Poisson pmf in log space (stable for large means).
    const double p_n =
        mu > 0 ? std::exp(n * std::log(mu) - mu - std::lgamma(n + 1.0)) : (n == 0 ? 1.0 : 0.0);
    if (p_n < 1e-300) continue;
    if (rn <= 0) {
      pmf[static_cast<std::size_t>(to_dn<int>(n, sensor))] += p_n;
      continue;
    }
    // DN = k when electrons in [g (k - 0.5 - black), g (k + 0.5 - black)).
    const double centre_dn = n / g + sensor.black_level_dn;
    const int k_lo = std::max(0, static_cast<int>(std::floor(centre_dn - 9 * rn / g)) - 1);
    const int k_hi = std::min(levels - 1, static_cast<int>(std::ceil(centre_dn + 9 * rn / g)) + 1);
    for (int k = k_lo; k <= k_hi; ++k) {
      const double lo = (k == 0) ? -1e300 : g * (k - 0.5 - sensor.black_level_dn);
      const double hi = (k == levels - 1) ? 1e300 : g * (k + 0.5 - sensor.black_level_dn);
      pmf[static_cast<std::size_t>(k)] +=
          p_n * (normal_cdf((hi - n) / rn) - normal_cdf((lo - n) / rn));
    }
  }
  // Walker/Vose alias table: O(1) exact sampling of the discrete DN distribution.
  double acc = 0;
  for (double p : pmf)
    acc += p;
  const std::size_t n = pmf.size();
  alias_prob.assign(n, 1.0);
  alias_index.assign(n, 0);
  std::vector<double> scaled(n);
  std::vector<std::uint32_t> small, large;
  for (std::size_t k = 0; k < n; ++k) {
    scaled[k] = pmf[k] / acc * static_cast<double>(n);
    alias_index[k] = static_cast<std::uint32_t>(k);
    (scaled[k] < 1.0 ? small : large).push_back(static_cast<std::uint32_t>(k));
  }
  while (!small.empty() && !large.empty()) {
    const std::uint32_t s = small.back(), l = large.back();
    small.pop_back();
    alias_prob[s] = scaled[s];
    alias_index[s] = l;
    scaled[l] -= 1.0 - scaled[s];
    if (scaled[l] < 1.0) {
      large.pop_back();
      small.push_back(l);
    }
  }
}

}  // namespace

PixelBox spot_box(const Spot& spot, int width, int height) {
  const double sigma = effective_sigma(spot);
  const double r = disc_radius(spot) + grid_step(spot);
  const double hx = r + std::abs(spot.blur_dx_px) / 2 + kBoxSigmas * sigma + 0.5;
  const double hy = r + std::abs(spot.blur_dy_px) / 2 + kBoxSigmas * sigma + 0.5;
  PixelBox box;
  if (!std::isfinite(spot.x_px) || !std::isfinite(spot.y_px)) return box;
  const double x0 = std::clamp(std::floor(spot.x_px - hx), 0.0, static_cast<double>(width));
  const double x1 = std::clamp(std::ceil(spot.x_px + hx) + 1, 0.0, static_cast<double>(width));
  const double y0 = std::clamp(std::floor(spot.y_px - hy), 0.0, static_cast<double>(height));
  const double y1 = std::clamp(std::ceil(spot.y_px + hy) + 1, 0.0, static_cast<double>(height));
  box.x0 = static_cast<int>(x0);
  box.x1 = static_cast<int>(x1);
  box.y0 = static_cast<int>(y0);
  box.y1 = static_cast<int>(y1);
  return box;
}

void SpotRenderer::evaluate(const Spot& spot, const PixelBox& box, double* out) {
  evaluate(spot, box, out, nullptr, nullptr);
}

void SpotRenderer::evaluate(const Spot& spot, const PixelBox& box, double* out, double* d_out_dx,
                            double* d_out_dy) {
  if (box.empty()) return;
  const double sigma = effective_sigma(spot);
  const double h = grid_step(spot);
  const double r = disc_radius(spot);
  const double length = std::hypot(spot.blur_dx_px, spot.blur_dy_px);
  const double ux = length > 0 ? spot.blur_dx_px / length : 1.0;
  const double uy = length > 0 ? spot.blur_dy_px / length : 0.0;
  const int na = static_cast<int>(std::ceil((r + std::abs(spot.blur_dx_px) / 2 + h) / h));
  const int nb = static_cast<int>(std::ceil((r + std::abs(spot.blur_dy_px) / 2 + h) / h));
  const int cols = 2 * na + 1, rows = 2 * nb + 1;

  // Anti-aliased area weights: coverage averaged over radii spread across one grid step, which
  // approximates the fraction of each h x h cell inside the (swept) disc. They depend only on
  // the shape, not on the position: cached for repeated evaluations.
  if (!(weights_valid_ && cached_r_ == r && cached_h_ == h && cached_bx_ == spot.blur_dx_px &&
        cached_by_ == spot.blur_dy_px)) {
    grow(weights_, static_cast<std::size_t>(rows) * cols);
    RowMap Wc(weights_.data(), rows, cols);
    constexpr double kRadiusOffsets[4] = {-0.375, -0.125, 0.125, 0.375};
    double sum = 0;
    for (int j = 0; j < rows; ++j) {
      const double py = (j - nb) * h;
      for (int i = 0; i < cols; ++i) {
        const double px = (i - na) * h;
        double w = 0;
        for (double off : kRadiusOffsets) {
          w += swept_coverage(px, py, r + off * h, ux, uy, length);
        }
        Wc(j, i) = w;
        sum += w;
      }
    }
    cached_total_ = sum;
    cached_r_ = r;
    cached_h_ = h;
    cached_bx_ = spot.blur_dx_px;
    cached_by_ = spot.blur_dy_px;
    weights_valid_ = true;
  }
  RowMap W(weights_.data(), rows, cols);
  const double total = cached_total_;
  const int bw = box.width(), bh = box.height();
  const bool gradient = d_out_dx != nullptr && d_out_dy != nullptr;
  RowMap out_map(out, bh, bw);
  if (total <= 0) {
    out_map.setZero();
    if (gradient) {
      RowMap(d_out_dx, bh, bw).setZero();
      RowMap(d_out_dy, bh, bw).setZero();
    }
    return;
  }

  // Pixel-integrated 1-D Gaussians for each grid column / row. Grid column i sits at
  // x + (i - na) h and pixel edge c at x0 - 0.5 + c; with h = 1/m their difference lies on the
  // lattice (base + q h), q = c m - i + na, so one erfc per lattice point serves all columns.
  // E(i, c) = Phi(u(c + 1)) - Phi(u(c)) with u = (edge - x - offset) / sigma, so its derivative
  // with respect to the spot centre x is -(phi(u(c + 1)) - phi(u(c))) / sigma: exact, from the
  // same lattice (the Gaussian density phi instead of its integral Phi).
  const int m = grid_steps_per_px(spot);
  const auto fill = [&](double base, int n_grid, int half, int n_px, RowMap& E, RowMap* dE) {
    const int n_lattice = n_px * m + n_grid;
    grow(cdf_, static_cast<std::size_t>(n_lattice));
    if (dE != nullptr) grow(pdf_, static_cast<std::size_t>(n_lattice));
    for (int q = 0; q < n_lattice; ++q) {
      const double u = (base + (q - (n_grid - 1 - half)) * h) / sigma;
      cdf_[static_cast<std::size_t>(q)] = normal_cdf(u);
      if (dE != nullptr) pdf_[static_cast<std::size_t>(q)] = normal_pdf(u) / sigma;
    }
    // Lattice index of (c, i): c m - i + half + (n_grid - 1 - half) = c m + n_grid - 1 - i.
    for (int i = 0; i < n_grid; ++i) {
      const double* f = cdf_.data() + (n_grid - 1 - i);
      for (int c = 0; c < n_px; ++c)
        E(i, c) = f[(c + 1) * m] - f[c * m];
      if (dE == nullptr) continue;
      const double* g = pdf_.data() + (n_grid - 1 - i);
      for (int c = 0; c < n_px; ++c)
        (*dE)(i, c) = g[c * m] - g[(c + 1) * m];
    }
  };
  const std::size_t n_ex = static_cast<std::size_t>(cols) * bw;
  const std::size_t n_ey = static_cast<std::size_t>(rows) * bh;
  const std::size_t n_t = static_cast<std::size_t>(rows) * bw;
  grow(ex_, gradient ? 2 * n_ex : n_ex);
  grow(ey_, gradient ? 2 * n_ey : n_ey);
  grow(tmp_, gradient ? 2 * n_t : n_t);
  RowMap Ex(ex_.data(), cols, bw), dEx(ex_.data() + n_ex, cols, gradient ? bw : 0);
  RowMap Ey(ey_.data(), rows, bh), dEy(ey_.data() + n_ey, rows, gradient ? bh : 0);
  fill(box.x0 - 0.5 - spot.x_px, cols, na, bw, Ex, gradient ? &dEx : nullptr);
  fill(box.y0 - 0.5 - spot.y_px, rows, nb, bh, Ey, gradient ? &dEy : nullptr);
  const double scale = spot.flux_e / total;
  RowMap T(tmp_.data(), rows, bw);
  T.noalias() = W * Ex;
  out_map.noalias() = Ey.transpose() * T;
  out_map *= scale;
  if (!gradient) return;
  // image = Ey^T W Ex: d/dx = Ey^T (W dEx), d/dy = dEy^T (W Ex).
  RowMap dT(tmp_.data() + n_t, rows, bw);
  dT.noalias() = W * dEx;
  RowMap dx_map(d_out_dx, bh, bw), dy_map(d_out_dy, bh, bw);
  dx_map.noalias() = Ey.transpose() * dT;
  dx_map *= scale;
  dy_map.noalias() = dEy.transpose() * T;
  dy_map *= scale;
}

void SpotRenderer::add_expected(const Spot& spot, float* electrons, int width, int height,
                                int stride) {
  const PixelBox box = spot_box(spot, width, height);
  if (box.empty()) return;
  grow(box_, static_cast<std::size_t>(box.width()) * box.height());
  evaluate(spot, box, box_.data());
  for (int y = box.y0; y < box.y1; ++y) {
    const double* src = box_.data() + static_cast<std::size_t>(y - box.y0) * box.width();
    float* dst = electrons + static_cast<std::size_t>(y) * stride;
    for (int x = box.x0; x < box.x1; ++x)
      dst[x] += static_cast<float>(src[x - box.x0]);
  }
}

void SpotRenderer::render_expected(std::span<const Spot> spots, const SensorModel& sensor,
                                   float* electrons, int width, int height, int stride) {
  for (int y = 0; y < height; ++y) {
    std::fill_n(electrons + static_cast<std::size_t>(y) * stride, width,
                static_cast<float>(sensor.background_e));
  }
  for (const Spot& s : spots)
    add_expected(s, electrons, width, height, stride);
}

void SpotRenderer::prepare_signal(std::span<const Spot> spots, int width, int height) {
  const std::size_t n = static_cast<std::size_t>(width) * height;
  if (signal_.size() < n || signal_width_ != width || signal_height_ != height) {
    signal_.assign(std::max(n, signal_.size()), 0.0f);
    signal_width_ = width;
    signal_height_ = height;
  }
  boxes_.clear();
  for (const Spot& s : spots) {
    const PixelBox box = spot_box(s, width, height);
    if (box.empty()) continue;
    boxes_.push_back(box);
    add_expected(s, signal_.data(), width, height, width);
  }
}

void SpotRenderer::build_background_table(const SensorModel& sensor) {
  const auto same = [&](const SensorModel& a) {
    return a.background_e == sensor.background_e && a.read_noise_e == sensor.read_noise_e &&
           a.gain_e_per_dn == sensor.gain_e_per_dn && a.full_scale_dn == sensor.full_scale_dn &&
           a.black_level_dn == sensor.black_level_dn;
  };
  if (table_valid_ && same(table_sensor_)) return;
  build_dn_alias_table(sensor.background_e, sensor, alias_prob_, alias_index_);
  table_sensor_ = sensor;
  table_valid_ = true;
}

template <typename Pixel>
void SpotRenderer::render_background_noisy(const SensorModel& sensor, std::mt19937_64& rng,
                                           Pixel* image, int width, int height, int stride) {
  build_background_table(sensor);
  // Background pixels: alias-method draw from the exact quantised distribution (fast path);
  // the high 32 bits pick the column, the low 32 bits decide column vs alias.
  const std::uint64_t levels = alias_prob_.size();
  for (int y = 0; y < height; ++y) {
    Pixel* row = image + static_cast<std::size_t>(y) * stride;
    for (int x = 0; x < width; ++x) {
      const std::uint64_t r = rng();
      const std::size_t k = static_cast<std::size_t>(((r >> 32) * levels) >> 32);
      const double u = static_cast<double>(r & 0xFFFFFFFFull) * 0x1.0p-32;
      row[x] = static_cast<Pixel>(u < alias_prob_[k] ? k : alias_index_[k]);
    }
  }
}

template <typename Pixel>
void SpotRenderer::render_spots_noisy(std::span<const Spot> spots, const SensorModel& sensor,
                                      std::mt19937_64& rng, Pixel* image, int width, int height,
                                      int stride) {
  prepare_signal(spots, width, height);
  // Spot pixels (overlapping boxes are drawn again from the same total mean: still exact).
  std::normal_distribution<double> read_noise(0.0, 1.0);
  for (const PixelBox& box : boxes_) {
    for (int y = box.y0; y < box.y1; ++y) {
      Pixel* row = image + static_cast<std::size_t>(y) * stride;
      const float* sig = signal_.data() + static_cast<std::size_t>(y) * width;
      for (int x = box.x0; x < box.x1; ++x) {
        row[x] = draw_dn<Pixel>(sensor.background_e + sig[x], sensor, rng, read_noise);
      }
    }
  }
  for (const PixelBox& box : boxes_) {
    for (int y = box.y0; y < box.y1; ++y) {
      std::fill(signal_.begin() + static_cast<std::ptrdiff_t>(y) * width + box.x0,
                signal_.begin() + static_cast<std::ptrdiff_t>(y) * width + box.x1, 0.0f);
    }
  }
}

void SpotRenderer::render_spots_gaussian(std::span<const Spot> spots, const SensorModel& sensor,
                                         std::span<const float> unit_normals, std::size_t offset,
                                         std::uint8_t* image, int width, int height, int stride) {
  SensorModel s = sensor;
  s.full_scale_dn = std::min(s.full_scale_dn, 255);
  prepare_signal(spots, width, height);
  const double read_var = s.read_noise_e * s.read_noise_e;
  const std::size_t n = unit_normals.size();
  offset %= n;
  for (const PixelBox& box : boxes_) {
    for (int y = box.y0; y < box.y1; ++y) {
      std::uint8_t* row = image + static_cast<std::size_t>(y) * stride;
      const float* sig = signal_.data() + static_cast<std::size_t>(y) * width;
      for (int x = box.x0; x < box.x1; ++x) {
        const double mu = s.background_e + sig[x];
        // Shot + read noise as one Gaussian of the exact mean and variance.
        const double z = unit_normals[offset];
        if (++offset == n) offset = 0;
        row[x] = to_dn<std::uint8_t>(mu + std::sqrt(mu + read_var) * z, s);
      }
    }
  }
  for (const PixelBox& box : boxes_) {
    for (int y = box.y0; y < box.y1; ++y) {
      std::fill(signal_.begin() + static_cast<std::ptrdiff_t>(y) * width + box.x0,
                signal_.begin() + static_cast<std::ptrdiff_t>(y) * width + box.x1, 0.0f);
    }
  }
}

// Background first, then the spots: the draws of render() since the simulator's first version.
template <typename Pixel>
void SpotRenderer::render_noisy(std::span<const Spot> spots, const SensorModel& sensor,
                                std::mt19937_64& rng, Pixel* image, int width, int height,
                                int stride) {
  render_background_noisy(sensor, rng, image, width, height, stride);
  render_spots_noisy(spots, sensor, rng, image, width, height, stride);
}

void SpotRenderer::render_background(const SensorModel& sensor, std::mt19937_64& rng,
                                     std::uint8_t* image, int width, int height, int stride) {
  SensorModel s = sensor;
  s.full_scale_dn = std::min(s.full_scale_dn, 255);
  render_background_noisy(s, rng, image, width, height, stride);
}

void SpotRenderer::render_spots(std::span<const Spot> spots, const SensorModel& sensor,
                                std::mt19937_64& rng, std::uint8_t* image, int width, int height,
                                int stride) {
  SensorModel s = sensor;
  s.full_scale_dn = std::min(s.full_scale_dn, 255);
  render_spots_noisy(spots, s, rng, image, width, height, stride);
}

void SpotRenderer::render(std::span<const Spot> spots, const SensorModel& sensor,
                          std::mt19937_64& rng, std::uint8_t* image, int width, int height,
                          int stride) {
  SensorModel s = sensor;
  s.full_scale_dn = std::min(s.full_scale_dn, 255);
  render_noisy(spots, s, rng, image, width, height, stride);
}

void SpotRenderer::render(std::span<const Spot> spots, const SensorModel& sensor,
                          std::mt19937_64& rng, std::uint16_t* image, int width, int height,
                          int stride) {
  SensorModel s = sensor;
  s.full_scale_dn = std::min(s.full_scale_dn, 65535);
  render_noisy(spots, s, rng, image, width, height, stride);
}

void SpotRenderer::render_noise_free(std::span<const Spot> spots, const SensorModel& sensor,
                                     std::uint8_t* image, int width, int height, int stride) {
  SensorModel s = sensor;
  s.full_scale_dn = std::min(s.full_scale_dn, 255);
  prepare_signal(spots, width, height);
  for (int y = 0; y < height; ++y) {
    std::uint8_t* row = image + static_cast<std::size_t>(y) * stride;
    const float* sig = signal_.data() + static_cast<std::size_t>(y) * width;
    for (int x = 0; x < width; ++x)
      row[x] = to_dn<std::uint8_t>(s.background_e + sig[x], s);
  }
  for (const PixelBox& box : boxes_) {
    for (int y = box.y0; y < box.y1; ++y) {
      std::fill(signal_.begin() + static_cast<std::ptrdiff_t>(y) * width + box.x0,
                signal_.begin() + static_cast<std::ptrdiff_t>(y) * width + box.x1, 0.0f);
    }
  }
}

SpotStatistics SpotRenderer::statistics(const Spot& spot, const SensorModel& sensor, int width,
                                        int height) {
  SpotStatistics st;
  const PixelBox box = spot_box(spot, width, height);
  if (box.empty()) return st;
  const std::size_t n = static_cast<std::size_t>(box.width()) * box.height();
  // The expected image and its exact derivatives with respect to the spot centre (Fisher
  // information).
  grow(stats_, 3 * n);
  double* buf = stats_.data();
  evaluate(spot, box, buf, buf + n, buf + 2 * n);
  // Per-pixel variance in e^2: shot (background + signal), read, quantisation (EMVA 1288).
  const double quant_var = sensor.gain_e_per_dn * sensor.gain_e_per_dn / 12.0;
  double fxx = 0, fxy = 0, fyy = 0, sum = 0, peak = 0, mx = 0, my = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double mu = buf[i];
    const double var = std::max(sensor.background_e, 0.0) + mu +
                       sensor.read_noise_e * sensor.read_noise_e + quant_var;
    const double dx = buf[n + i];
    const double dy = buf[2 * n + i];
    fxx += dx * dx / var;
    fxy += dx * dy / var;
    fyy += dy * dy / var;
    sum += mu;
    mx += mu * (box.x0 + static_cast<int>(i % static_cast<std::size_t>(box.width())));
    my += mu * (box.y0 + static_cast<int>(i / static_cast<std::size_t>(box.width())));
    peak = std::max(peak, mu);
  }
  const double det = fxx * fyy - fxy * fxy;
  if (det > 0) {
    st.crlb_sigma_x_px = std::sqrt(fyy / det);
    st.crlb_sigma_y_px = std::sqrt(fxx / det);
  } else {
    st.crlb_sigma_x_px = st.crlb_sigma_y_px = INFINITY;
  }
  st.sigma_px = std::sqrt(
      0.5 * (st.crlb_sigma_x_px * st.crlb_sigma_x_px + st.crlb_sigma_y_px * st.crlb_sigma_y_px));
  st.peak_signal_e = peak;
  st.peak_dn = (sensor.background_e + peak) / sensor.gain_e_per_dn + sensor.black_level_dn;
  st.saturated = st.peak_dn >= sensor.full_scale_dn;
  st.in_image_fraction = spot.flux_e > 0 ? sum / spot.flux_e : 0.0;
  st.centroid_x_px = sum > 0 ? mx / sum : spot.x_px;
  st.centroid_y_px = sum > 0 ? my / sum : spot.y_px;
  return st;
}

namespace {
SpotRenderer& thread_renderer() {
  thread_local SpotRenderer renderer;
  return renderer;
}
}  // namespace

void render_spots(std::span<const Spot> spots, const SensorModel& sensor, std::mt19937_64& rng,
                  std::uint8_t* image, int width, int height, int stride) {
  thread_renderer().render(spots, sensor, rng, image, width, height, stride);
}

void render_spots_noise_free(std::span<const Spot> spots, const SensorModel& sensor,
                             std::uint8_t* image, int width, int height, int stride) {
  thread_renderer().render_noise_free(spots, sensor, image, width, height, stride);
}

void render_spots_expected(std::span<const Spot> spots, const SensorModel& sensor, float* electrons,
                           int width, int height, int stride) {
  thread_renderer().render_expected(spots, sensor, electrons, width, height, stride);
}

SpotStatistics spot_statistics(const Spot& spot, const SensorModel& sensor, int width, int height) {
  return thread_renderer().statistics(spot, sensor, width, height);
}

namespace {

struct DnTable {
  float mu_e = 0;
  std::vector<double> prob;
  std::vector<std::uint32_t> index;
};

// The values shared by at least 1 % of the pixels (a 1/61 subsample), at most 8: the flat
// regions of a scene (board squares, surround) have exactly equal expected values.
std::vector<DnTable> frequent_value_tables(const float* electrons, int stride_e, int width,
                                           int height, const SensorModel& sensor) {
  std::vector<float> sample;
  for (std::size_t i = 0, n = static_cast<std::size_t>(width) * height; i < n; i += 61)
    sample.push_back(electrons[(i / width) * stride_e + i % width]);
  std::sort(sample.begin(), sample.end());
  std::vector<DnTable> tables;
  for (std::size_t i = 0; i < sample.size() && tables.size() < 8;) {
    std::size_t j = i;
    while (j < sample.size() && sample[j] == sample[i])
      ++j;
    if (j - i >= std::max<std::size_t>(1, sample.size() / 100)) {
      DnTable t;
      t.mu_e = sample[i];
      build_dn_alias_table(sample[i], sensor, t.prob, t.index);
      tables.push_back(std::move(t));
    }
    i = j;
  }
  return tables;
}

}  // namespace

void expose(const float* electrons, int stride_e, const SensorModel& sensor, std::mt19937_64& rng,
            std::uint8_t* image, int width, int height, int stride) {
  SensorModel s = sensor;
  s.full_scale_dn = std::min(s.full_scale_dn, 255);
  // Exact either way: an alias table draw (one random number) for the frequent values, a
  // Poisson + Gaussian draw for the rest (edges).
  const std::vector<DnTable> tables = frequent_value_tables(electrons, stride_e, width, height, s);
  std::normal_distribution<double> read_noise(0.0, 1.0);
  for (int y = 0; y < height; ++y) {
    const float* mu = electrons + static_cast<std::size_t>(y) * stride_e;
    std::uint8_t* row = image + static_cast<std::size_t>(y) * stride;
    for (int x = 0; x < width; ++x) {
      const DnTable* table = nullptr;
      for (const DnTable& t : tables) {
        if (t.mu_e == mu[x]) {
          table = &t;
          break;
        }
      }
      if (table == nullptr) {
        row[x] = draw_dn<std::uint8_t>(mu[x], s, rng, read_noise);
        continue;
      }
      const std::uint64_t r = rng();
      const std::size_t k = static_cast<std::size_t>(((r >> 32) * table->prob.size()) >> 32);
      const double u = static_cast<double>(r & 0xFFFFFFFFull) * 0x1.0p-32;
      row[x] = static_cast<std::uint8_t>(u < table->prob[k] ? k : table->index[k]);
    }
  }
}

void expose_noise_free(const float* electrons, int stride_e, const SensorModel& sensor,
                       std::uint8_t* image, int width, int height, int stride) {
  SensorModel s = sensor;
  s.full_scale_dn = std::min(s.full_scale_dn, 255);
  for (int y = 0; y < height; ++y) {
    const float* mu = electrons + static_cast<std::size_t>(y) * stride_e;
    std::uint8_t* row = image + static_cast<std::size_t>(y) * stride;
    for (int x = 0; x < width; ++x)
      row[x] = to_dn<std::uint8_t>(mu[x], s);
  }
}

}  // namespace storetrack::sim
