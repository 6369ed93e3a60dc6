// Renderer against its own model's truth: centroids, flux, noise statistics, saturation.
#include <algorithm>
#include <cmath>
#include <random>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>

#include "storetrack/sim/render.hpp"

namespace storetrack::sim {
namespace {

constexpr int kW = 96, kH = 64;

struct Moments {
  double sum = 0, x = 0, y = 0;
};

// Background-subtracted first moments over the whole image.
Moments moments(const std::vector<float>& img, double background) {
  Moments m;
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const double v = img[static_cast<std::size_t>(y) * kW + x] - background;
      m.sum += v;
      m.x += v * x;
      m.y += v * y;
    }
  }
  m.x /= m.sum;
  m.y /= m.sum;
  return m;
}

TEST(Render, NoiseFreeCentroidMatchesTruthOverSubpixelPhases) {
  SensorModel sensor;
  std::vector<float> img(kW * kH);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> phase(0.0, 1.0);
  double worst = 0;
  for (double diameter : {0.0, 2.0, 5.0, 11.0}) {
    for (double sigma : {0.5, 0.8, 1.5}) {
      for (int trial = 0; trial < 6; ++trial) {
        Spot s;
        s.x_px = 40 + phase(rng);
        s.y_px = 30 + phase(rng);
        s.disc_diameter_px = diameter;
        s.psf_sigma_px = sigma;
        s.flux_e = 30000;
        s.blur_dx_px = trial < 3 ? 0.0 : 7.3 * (phase(rng) - 0.5);
        s.blur_dy_px = trial < 3 ? 0.0 : 5.1 * (phase(rng) - 0.5);
        const Spot spots[] = {s};
        render_spots_expected(spots, sensor, img.data(), kW, kH, kW);
        const Moments m = moments(img, sensor.background_e);
        EXPECT_NEAR(m.sum, s.flux_e, 1e-3 * s.flux_e);
        worst = std::max({worst, std::abs(m.x - s.x_px), std::abs(m.y - s.y_px)});
      }
    }
  }
  // Pixel-sampling bias of a pixel-integrated spot with sigma >= 0.5 px is < 0.002 px.
  EXPECT_LT(worst, 0.002);
}

TEST(Render, DiscWidthMatchesModelVariance) {
  // Second moment of disc (*) Gaussian (*) pixel box: R^2/4 + sigma^2 + 1/12 per axis.
  SensorModel sensor;
  std::vector<float> img(kW * kH);
  Spot s;
  s.x_px = 47.3;
  s.y_px = 31.6;
  s.disc_diameter_px = 8;
  s.psf_sigma_px = 0.9;
  s.flux_e = 1e5;
  const Spot spots[] = {s};
  render_spots_expected(spots, sensor, img.data(), kW, kH, kW);
  double sum = 0, vxx = 0;
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const double v = img[static_cast<std::size_t>(y) * kW + x] - sensor.background_e;
      sum += v;
      vxx += v * (x - s.x_px) * (x - s.x_px);
    }
  }
  const double expected = 4.0 * 4.0 / 4 + 0.9 * 0.9 + 1.0 / 12;
  EXPECT_NEAR(vxx / sum, expected, 0.03 * expected);
}

TEST(Render, MotionBlurSpreadsAlongTheBlurVector) {
  SensorModel sensor;
  std::vector<float> img(kW * kH);
  Spot s;
  s.x_px = 47.5;
  s.y_px = 31.5;
  s.disc_diameter_px = 0;
  s.psf_sigma_px = 0.6;
  s.flux_e = 1e5;
  s.blur_dx_px = 12;
  const Spot spots[] = {s};
  render_spots_expected(spots, sensor, img.data(), kW, kH, kW);
  double sum = 0, vxx = 0, vyy = 0;
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const double v = img[static_cast<std::size_t>(y) * kW + x] - sensor.background_e;
      sum += v;
      vxx += v * (x - s.x_px) * (x - s.x_px);
      vyy += v * (y - s.y_px) * (y - s.y_px);
    }
  }
  // Uniform segment of length L: variance L^2/12.
  EXPECT_NEAR(vxx / sum, 144.0 / 12 + 0.36 + 1.0 / 12, 0.1);
  EXPECT_NEAR(vyy / sum, 0.36 + 1.0 / 12, 0.05);
}

TEST(Render, NoisyBackgroundMatchesSensorModel) {
  SensorModel sensor;
  sensor.background_e = 200;
  sensor.read_noise_e = 15;
  sensor.gain_e_per_dn = 10;
  std::vector<std::uint8_t> img(kW * kH);
  std::mt19937_64 rng(3);
  double sum = 0, sum2 = 0;
  int n = 0;
  for (int frame = 0; frame < 20; ++frame) {
    render_spots({}, sensor, rng, img.data(), kW, kH, kW);
    for (std::uint8_t v : img) {
      sum += v;
      sum2 += static_cast<double>(v) * v;
      ++n;
    }
  }
  const double mean = sum / n;
  const double var = sum2 / n - mean * mean;
  // EMVA 1288: var_DN = (mu_e + read^2) / g^2 + 1/12.
  const double expected_var = (200.0 + 225.0) / 100.0 + 1.0 / 12;
  EXPECT_NEAR(mean, 20.0, 0.02);
  EXPECT_NEAR(var, expected_var, 0.04 * expected_var);
}

TEST(Render, SpotPixelNoiseIsPoissonPlusRead) {
  SensorModel sensor;
  sensor.gain_e_per_dn = 8;
  Spot s;
  s.x_px = 40;
  s.y_px = 30;
  s.disc_diameter_px = 6;
  s.psf_sigma_px = 0.7;
  s.flux_e = 20000;
  const Spot spots[] = {s};
  std::vector<float> mean_img(kW * kH);
  render_spots_expected(spots, sensor, mean_img.data(), kW, kH, kW);
  const double mu = mean_img[30 * kW + 40];
  std::vector<std::uint8_t> img(kW * kH);
  std::mt19937_64 rng(11);
  double sum = 0, sum2 = 0;
  const int frames = 3000;
  for (int f = 0; f < frames; ++f) {
    render_spots(spots, sensor, rng, img.data(), kW, kH, kW);
    const double v = img[30 * kW + 40];
    sum += v;
    sum2 += v * v;
  }
  const double mean = sum / frames, var = sum2 / frames - mean * mean;
  const double g = sensor.gain_e_per_dn;
  EXPECT_NEAR(mean, mu / g, 0.1);
  const double expected_var = (mu + sensor.read_noise_e * sensor.read_noise_e) / (g * g) + 1.0 / 12;
  EXPECT_NEAR(var, expected_var, 0.1 * expected_var);
}

TEST(Render, SaturationClipsAtFullScale) {
  SensorModel sensor;
  Spot s;
  s.x_px = 40;
  s.y_px = 30;
  s.flux_e = 1e7;
  const Spot spots[] = {s};
  std::vector<std::uint8_t> img(kW * kH);
  std::mt19937_64 rng(1);
  render_spots(spots, sensor, rng, img.data(), kW, kH, kW);
  EXPECT_EQ(img[30 * kW + 40], 255);
  const SpotStatistics st = spot_statistics(s, sensor, kW, kH);
  EXPECT_TRUE(st.saturated);
  render_spots_noise_free(spots, sensor, img.data(), kW, kH, kW);
  EXPECT_EQ(img[30 * kW + 40], 255);
  EXPECT_EQ(img[0], static_cast<std::uint8_t>(std::lround(sensor.background_e / 20)));
}

TEST(Render, SpotsLeavingTheImageLoseFluxGracefully) {
  SensorModel sensor;
  Spot s;
  s.x_px = -1.0;  // centre outside the image
  s.y_px = 10;
  s.disc_diameter_px = 6;
  s.flux_e = 1e4;
  const SpotStatistics st = spot_statistics(s, sensor, kW, kH);
  EXPECT_GT(st.in_image_fraction, 0.1);
  EXPECT_LT(st.in_image_fraction, 0.5);
  s.x_px = -50;
  EXPECT_EQ(spot_statistics(s, sensor, kW, kH).in_image_fraction, 0.0);
  std::vector<std::uint8_t> img(kW * kH);
  std::mt19937_64 rng(1);
  const Spot spots[] = {s};
  render_spots(spots, sensor, rng, img.data(), kW, kH, kW);  // must not touch memory outside
}

TEST(Render, CramerRaoBoundMatchesMonteCarloOfAnEfficientEstimator) {
  // Shot-noise-limited regime: the CRLB falls as 1/sqrt(flux); a weighted moment estimator on a
  // bright point-like spot reaches it within ~25 %.
  SensorModel sensor;
  sensor.background_e = 0;
  sensor.read_noise_e = 0;
  sensor.gain_e_per_dn = 1;
  sensor.full_scale_dn = 65535;
  sensor.bits = 16;
  Spot s;
  s.x_px = 40.2;
  s.y_px = 30.7;
  s.disc_diameter_px = 0;
  s.psf_sigma_px = 1.2;
  s.flux_e = 4000;
  const SpotStatistics st = spot_statistics(s, sensor, kW, kH);
  const SpotStatistics st4 = [&] {
    Spot b = s;
    b.flux_e *= 4;
    return spot_statistics(b, sensor, kW, kH);
  }();
  EXPECT_NEAR(st.sigma_px / st4.sigma_px, 2.0, 0.05);
  // For a Gaussian spot in pure shot noise the moment centroid is efficient: var = s^2 / N with
  // s^2 = sigma^2 + 1/12 (pixel).
  const double expected = std::sqrt((1.2 * 1.2 + 1.0 / 12) / 4000);
  EXPECT_NEAR(st.sigma_px, expected, 0.1 * expected);
  SpotRenderer renderer;
  std::vector<std::uint16_t> img(kW * kH);
  std::mt19937_64 rng(5);
  double sx = 0, sxx = 0;
  const int trials = 400;
  for (int t = 0; t < trials; ++t) {
    const Spot spots[] = {s};
    renderer.render(spots, sensor, rng, img.data(), kW, kH, kW);
    double sum = 0, mx = 0;
    for (int y = 0; y < kH; ++y)
      for (int x = 0; x < kW; ++x) {
        sum += img[static_cast<std::size_t>(y) * kW + x];
        mx += img[static_cast<std::size_t>(y) * kW + x] * static_cast<double>(x);
      }
    const double e = mx / sum - s.x_px;
    sx += e;
    sxx += e * e;
  }
  const double sd = std::sqrt(sxx / trials - (sx / trials) * (sx / trials));
  EXPECT_NEAR(sd, st.crlb_sigma_x_px, 0.2 * st.crlb_sigma_x_px);
}

TEST(Render, PositionDerivativeMatchesCentralDifferences) {
  // The Fisher information of statistics() uses evaluate()'s analytic derivative with respect to
  // the spot centre: checked against central differences of evaluate() itself, for a point
  // spot, a disc, a blurred disc and a disc at the image corner. Step 1e-4 px: the truncation
  // error (step^2 / 6 times the third derivative) is below 1e-8 of the peak, rounding about
  // 1e-12 of it.
  SpotRenderer renderer;
  for (const auto& [x, y, disc, blur_x, blur_y] :
       {std::tuple{40.3, 30.8, 0.0, 0.0, 0.0}, std::tuple{20.55, 41.1, 3.0, 0.0, 0.0},
        std::tuple{51.9, 22.2, 2.5, 4.0, -1.5}, std::tuple{1.2, 2.7, 2.0, 0.0, 2.0}}) {
    Spot s;
    s.x_px = x;
    s.y_px = y;
    s.disc_diameter_px = disc;
    s.blur_dx_px = blur_x;
    s.blur_dy_px = blur_y;
    s.psf_sigma_px = 0.8;
    s.flux_e = 5000;
    const PixelBox box = spot_box(s, kW, kH);
    const std::size_t n = static_cast<std::size_t>(box.width()) * box.height();
    std::vector<double> img(n), d_dx(n), d_dy(n), plus(n), minus(n);
    renderer.evaluate(s, box, img.data(), d_dx.data(), d_dy.data());
    const double peak = *std::max_element(img.begin(), img.end());
    constexpr double kStep = 1e-4;
    for (int axis = 0; axis < 2; ++axis) {
      Spot p = s, m = s;
      (axis == 0 ? p.x_px : p.y_px) += kStep;
      (axis == 0 ? m.x_px : m.y_px) -= kStep;
      renderer.evaluate(p, box, plus.data());
      renderer.evaluate(m, box, minus.data());
      const std::vector<double>& analytic = axis == 0 ? d_dx : d_dy;
      double worst = 0, largest = 0;
      for (std::size_t i = 0; i < n; ++i) {
        worst = std::max(worst, std::abs((plus[i] - minus[i]) / (2 * kStep) - analytic[i]));
        largest = std::max(largest, std::abs(analytic[i]));
      }
      EXPECT_LT(worst, 1e-6 * peak) << "spot at " << x << ", " << y << " axis " << axis;
      EXPECT_GT(largest, 0.1 * peak) << "the derivative is not trivially zero";
    }
    // The image itself is the one evaluate() without derivatives gives.
    renderer.evaluate(s, box, plus.data());
    for (std::size_t i = 0; i < n; ++i)
      ASSERT_EQ(plus[i], img[i]);
  }
}

}  // namespace
}  // namespace storetrack::sim
