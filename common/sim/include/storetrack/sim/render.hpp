// Physical rendering of retro-reflective marks into 8- or 16-bit mono frames.
//
// Spot model (docs/conventions.md pixel convention: centre of the top-left pixel is (0, 0)):
//   irradiance = flux_e * [uniform disc of diameter disc_diameter_px]
//                       (*) [line segment blur_d over the exposure]
//                       (*) [isotropic Gaussian PSF of psf_sigma_px],
// integrated exactly over each square pixel. The disc (*) segment part is sampled on a grid
// that is point-symmetric about the spot centre with anti-aliased area weights; each grid
// sample's Gaussian is integrated over the pixel with erf (separable), so the pixel-integrated
// image is point-symmetric about (x_px, y_px) and its centroid is exact up to the physical
// pixel-sampling effect (see tests/common/sim/test_render.cpp).
//
// Sensor model (EMVA 1288 linear camera model): electrons = Poisson(background + signal)
// + Normal(0, read_noise); DN = round(electrons / gain + black_level), clipped to
// [0, full_scale_dn] (saturation). The noise-free variants return the expected electrons (for
// Cramer-Rao bounds) or the quantised expectation.
#pragma once

#include <cstdint>
#include <random>
#include <span>
#include <vector>

namespace storetrack::sim {

/// One mark's image during one exposure.
struct Spot {
  double x_px = 0, y_px = 0;      ///< spot centre at the exposure MID-point [px]
  double psf_sigma_px = 0.7;      ///< Gaussian PSF standard deviation (optics + defocus) [px]
  double disc_diameter_px = 4.0;  ///< image diameter of the retro disc [px] (0: point source)
  double flux_e = 20000;          ///< total photo-electrons of the spot over the exposure
  /// Motion of the spot centre during the exposure [px]: it moves uniformly from
  /// (x - dx/2, y - dy/2) at exposure start to (x + dx/2, y + dy/2) at exposure end.
  double blur_dx_px = 0, blur_dy_px = 0;
};

/// Linear sensor (EMVA 1288). Defaults: a 400 fps 8-bit industrial CMOS with a ~5 ke- range.
struct SensorModel {
  double background_e = 100;  ///< mean background per pixel (dark + ambient) [e-]
  double read_noise_e = 12;   ///< temporal read noise, standard deviation [e-]
  double gain_e_per_dn = 20;  ///< conversion: electrons per digital number
  int full_scale_dn = 255;    ///< saturation level [DN]
  int bits = 8;               ///< output bits (8: uint8 images, 9..16: uint16 images)
  double black_level_dn = 0;  ///< offset added before quantisation [DN]
};

/// Half-open pixel rectangle [x0, x1) x [y0, y1).
struct PixelBox {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;
  int width() const { return x1 - x0; }
  int height() const { return y1 - y0; }
  bool empty() const { return x1 <= x0 || y1 <= y0; }
};

/// Statistics of one spot under a sensor model, from the same renderer.
struct SpotStatistics {
  double crlb_sigma_x_px = 0;    ///< Cramer-Rao bound of the centroid, column [px]
  double crlb_sigma_y_px = 0;    ///< Cramer-Rao bound of the centroid, row [px]
  double sigma_px = 0;           ///< isotropic per-axis sigma: sqrt((sx^2 + sy^2) / 2) [px]
  double peak_signal_e = 0;      ///< largest expected signal in one pixel (no background) [e-]
  double peak_dn = 0;            ///< expected DN of that pixel including background
  bool saturated = false;        ///< peak_dn reaches full scale
  double in_image_fraction = 0;  ///< fraction of flux_e landing inside the image
  /// Expected centroid of the in-image part of the spot (differs from the centre when the
  /// spot is clipped by the image border) [px].
  double centroid_x_px = 0, centroid_y_px = 0;
};

/// Pixels a spot lights to within 1e-9 of its flux (6.5 sigma beyond disc + blur), clipped.
PixelBox spot_box(const Spot& spot, int width, int height);

/// Renderer with reusable scratch memory: after the first frames of a given size it does not
/// allocate. Not thread-safe (one per thread).
class SpotRenderer {
 public:
  /// Adds the spot's expected signal electrons (no background) into a float image.
  void add_expected(const Spot& spot, float* electrons, int width, int height, int stride);

  /// Expected electrons per pixel including the background (noise-free, not quantised).
  void render_expected(std::span<const Spot> spots, const SensorModel& sensor, float* electrons,
                       int width, int height, int stride);

  /// Noisy frame (shot + read noise, quantisation, saturation). stride in elements.
  void render(std::span<const Spot> spots, const SensorModel& sensor, std::mt19937_64& rng,
              std::uint8_t* image, int width, int height, int stride);
  void render(std::span<const Spot> spots, const SensorModel& sensor, std::mt19937_64& rng,
              std::uint16_t* image, int width, int height, int stride);

  /// The two halves of render() (8-bit), for a source that keeps a pool of backgrounds:
  /// render_background draws every pixel from the no-spot distribution; render_spots draws
  /// the pixels of every spot's box again over whatever `image` holds (its boxes: drawn_boxes()).
  void render_background(const SensorModel& sensor, std::mt19937_64& rng, std::uint8_t* image,
                         int width, int height, int stride);
  void render_spots(std::span<const Spot> spots, const SensorModel& sensor, std::mt19937_64& rng,
                    std::uint8_t* image, int width, int height, int stride);
  /// render_spots with the shot and read noise of each pixel as one Gaussian of the exact mean
  /// and variance, its standard normal read from `unit_normals` at offset, offset + 1, ...
  /// (wrapping): about 50 times cheaper than the exact Poisson draw, for a source that must
  /// keep 400 fps (the spots of a close camera cover tens of thousands of pixels).
  void render_spots_gaussian(std::span<const Spot> spots, const SensorModel& sensor,
                             std::span<const float> unit_normals, std::size_t offset,
                             std::uint8_t* image, int width, int height, int stride);
  /// The boxes the last render / render_spots drew (clipped to the image, none empty).
  std::span<const PixelBox> drawn_boxes() const { return boxes_; }

  /// Noise-free quantised frame: round(expected / gain + black), clipped.
  void render_noise_free(std::span<const Spot> spots, const SensorModel& sensor,
                         std::uint8_t* image, int width, int height, int stride);

  /// Centroid Cramer-Rao bound (shot + read + quantisation noise), peak and saturation.
  SpotStatistics statistics(const Spot& spot, const SensorModel& sensor, int width, int height);

  /// Expected signal electrons of one spot on an explicit box (row-major, box.width() per row).
  void evaluate(const Spot& spot, const PixelBox& box, double* out);
  /// The same, with its exact derivatives with respect to the spot centre (x_px, y_px) [e-/px]
  /// in d_out_dx and d_out_dy (same layout; both or neither).
  void evaluate(const Spot& spot, const PixelBox& box, double* out, double* d_out_dx,
                double* d_out_dy);

 private:
  template <typename Pixel>
  void render_noisy(std::span<const Spot> spots, const SensorModel& sensor, std::mt19937_64& rng,
                    Pixel* image, int width, int height, int stride);
  template <typename Pixel>
  void render_background_noisy(const SensorModel& sensor, std::mt19937_64& rng, Pixel* image,
                               int width, int height, int stride);
  template <typename Pixel>
  void render_spots_noisy(std::span<const Spot> spots, const SensorModel& sensor,
                          std::mt19937_64& rng, Pixel* image, int width, int height, int stride);
  void prepare_signal(std::span<const Spot> spots, int width, int height);
  void build_background_table(const SensorModel& sensor);

  std::vector<double> weights_, ex_, ey_, tmp_, box_, stats_, cdf_, pdf_;
  // Shape key of the cached weights_ (disc radius, grid step, blur vector).
  bool weights_valid_ = false;
  double cached_r_ = 0, cached_h_ = 0, cached_bx_ = 0, cached_by_ = 0, cached_total_ = 0;
  std::vector<float> signal_;  // width * height expected signal, zero outside spot boxes
  std::vector<PixelBox> boxes_;
  int signal_width_ = 0, signal_height_ = 0;
  // Alias table of the background-pixel DN distribution (exact Poisson (*) Gaussian, quantised).
  std::vector<double> alias_prob_;
  std::vector<std::uint32_t> alias_index_;
  SensorModel table_sensor_{};
  bool table_valid_ = false;
};

/// The sensor model above applied to an expected image (electrons per pixel, background
/// included, stride_e in floats): each pixel Poisson(mu) + N(0, read_noise), quantised and
/// clipped like the spot pixels of SpotRenderer::render. Any scene rendered to expected
/// electrons (board images, common/sim board_render.hpp) gets its noise here.
void expose(const float* electrons, int stride_e, const SensorModel& sensor, std::mt19937_64& rng,
            std::uint8_t* image, int width, int height, int stride);
/// Noise-free: round(mu / gain + black), clipped (the quantised mean).
void expose_noise_free(const float* electrons, int stride_e, const SensorModel& sensor,
                       std::uint8_t* image, int width, int height, int stride);

/// Convenience wrappers over a thread-local SpotRenderer (8-bit images, stride in bytes).
void render_spots(std::span<const Spot> spots, const SensorModel& sensor, std::mt19937_64& rng,
                  std::uint8_t* image, int width, int height, int stride);
/// Noise-free quantised variant.
void render_spots_noise_free(std::span<const Spot> spots, const SensorModel& sensor,
                             std::uint8_t* image, int width, int height, int stride);
/// Expected electrons per pixel including background (for Cramer-Rao computations);
/// stride in floats.
void render_spots_expected(std::span<const Spot> spots, const SensorModel& sensor, float* electrons,
                           int width, int height, int stride);
/// Centroid Cramer-Rao bound and peak of one spot (see SpotRenderer::statistics).
SpotStatistics spot_statistics(const Spot& spot, const SensorModel& sensor, int width = 1920,
                               int height = 1024);

}  // namespace storetrack::sim
