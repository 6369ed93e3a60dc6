// Centroider against simulator truth: bias, RMS vs the Cramer-Rao bound, predicted sigma,
// flags, ROIs, Mono16, capacity limits, bad input and the no-allocation guarantee.
#include <gtest/gtest.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <vector>

#include "centroid_eval.hpp"
#include "storetrack/centroid/centroider.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/sim/render.hpp"
#include "storetrack/testing/counting_allocator.hpp"

namespace storetrack::centroid {
namespace {

using frame::FrameView;
using frame::PixelFormat;

FrameView view_of(const std::vector<std::uint8_t>& image, int width, int height) {
  FrameView f;
  f.pixels = image.data();
  f.width = width;
  f.height = height;
  f.stride_bytes = width;
  f.format = PixelFormat::kMono8;
  f.bits_per_pixel = 8;
  return f;
}

FrameView view_of(const std::vector<std::uint16_t>& image, int width, int height, int bits) {
  FrameView f;
  f.pixels = reinterpret_cast<const std::uint8_t*>(image.data());
  f.width = width;
  f.height = height;
  f.stride_bytes = 2 * width;
  f.format = PixelFormat::kMono16;
  f.bits_per_pixel = bits;
  return f;
}

CentroidConfig config_for(const sim::SensorModel& sensor) {
  CentroidConfig config;
  config.read_noise_e = sensor.read_noise_e;
  config.gain_e_per_dn = sensor.gain_e_per_dn;
  config.black_level_dn = sensor.black_level_dn;
  config.saturation_dn = sensor.full_scale_dn;
  return config;
}

sim::Spot gaussian_spot(double sigma_px, double flux_e) {
  sim::Spot s;
  s.psf_sigma_px = sigma_px;
  s.disc_diameter_px = 0;
  s.flux_e = flux_e;
  return s;
}

struct MonteCarloResult {
  eval::ErrorStats errors;
  int flagged = 0;
};

// Renders `frames` frames of `per_frame` random spots, centroids them and compares with truth.
MonteCarloResult monte_carlo(const sim::Spot& prototype, const sim::SensorModel& sensor, int frames,
                             int per_frame, std::uint64_t seed, bool mono16 = false) {
  constexpr int kWidth = 640, kHeight = 320;
  std::mt19937_64 rng(seed);
  sim::SpotRenderer renderer;
  // The bound of a spot well inside the frame (it barely depends on the sub-pixel phase).
  sim::Spot centred = prototype;
  centred.x_px = kWidth / 2 + 0.25;
  centred.y_px = kHeight / 2 + 0.4;
  const eval::CramerRao crb = eval::cramer_rao(renderer, centred, sensor, kWidth, kHeight);
  Centroider centroider(config_for(sensor), kWidth, kHeight);
  std::vector<std::uint8_t> image8(kWidth * kHeight);
  std::vector<std::uint16_t> image16(kWidth * kHeight);
  std::vector<Blob> blobs(128);
  MonteCarloResult result;
  for (int f = 0; f < frames; ++f) {
    const auto spots = eval::random_spots(prototype, per_frame, kWidth, kHeight, 24, 24, rng);
    int n = 0;
    if (mono16) {
      renderer.render(spots, sensor, rng, image16.data(), kWidth, kHeight, kWidth);
      n = centroider.process(view_of(image16, kWidth, kHeight, sensor.bits), blobs);
    } else {
      renderer.render(spots, sensor, rng, image8.data(), kWidth, kHeight, kWidth);
      n = centroider.process(view_of(image8, kWidth, kHeight), blobs);
    }
    EXPECT_GE(n, 0);
    if (n < 0) continue;
    for (const eval::Match& m : eval::match(spots, std::span(blobs.data(), n), 3.0)) {
      if (m.blob < 0) {
        ++result.errors.missed;
        continue;
      }
      if (blobs[m.blob].flags != 0) ++result.flagged;
      result.errors.add(m.error_x_px, m.error_y_px, blobs[m.blob].sigma_px, crb.sigma_px);
    }
  }
  return result;
}

void print(const char* what, const MonteCarloResult& r) {
  const auto& e = r.errors;
  std::printf(
      "%-34s n=%5d missed=%d flagged=%d bias=(%+.4f, %+.4f) rms=%.4f crb=%.4f ratio=%.3f "
      "predicted=%.4f (pred/obs %.3f)\n",
      what, e.n, e.missed, r.flagged, e.bias_x(), e.bias_y(), e.rms(), e.rms_crb(),
      e.ratio_to_crb(), e.rms_predicted(), e.rms_predicted() / e.rms());
}

// Statistical slack: with n samples, the RMS is known to ~1/sqrt(2n) relative.
void expect_accurate(const MonteCarloResult& r, double max_ratio) {
  const auto& e = r.errors;
  ASSERT_GT(e.n, 500);
  EXPECT_EQ(e.missed, 0);
  EXPECT_EQ(r.flagged, 0);
  EXPECT_LT(std::abs(e.bias_x()), 0.01);
  EXPECT_LT(std::abs(e.bias_y()), 0.01);
  EXPECT_LE(e.ratio_to_crb(), max_ratio);
  EXPECT_NEAR(e.rms_predicted() / e.rms(), 1.0, 0.15);
}

// Blob flags go on the wire unchanged.
static_assert(blob_flags::kSaturated == msg::mark_flags::kSaturated);
static_assert(blob_flags::kBorder == msg::mark_flags::kBorder);
static_assert(blob_flags::kMerged == msg::mark_flags::kMerged);
static_assert(blob_flags::kElongated == msg::mark_flags::kElongated);

TEST(CramerRao, AgreesWithSimulatorStatistics) {
  // Independent computation (with flux as nuisance) vs the simulator's (x, y only): the
  // cross terms vanish by symmetry, so the two must agree closely.
  sim::SensorModel sensor;
  sim::SpotRenderer renderer;
  for (double sigma : {0.8, 1.5, 2.5}) {
    sim::Spot s = gaussian_spot(sigma, 20000);
    s.x_px = 100.3;
    s.y_px = 50.7;
    const auto ours = eval::cramer_rao(renderer, s, sensor, 200, 100);
    const auto theirs = renderer.statistics(s, sensor, 200, 100);
    EXPECT_NEAR(ours.sigma_px / theirs.sigma_px, 1.0, 0.03) << "sigma " << sigma;
  }
}

TEST(Centroider, GaussianMarksAtTypicalSignalReachTheBound) {
  // sigma 1.5 px Gaussian marks (the reference case), default 8-bit sensor.
  const sim::SensorModel sensor;
  const auto r = monte_carlo(gaussian_spot(1.5, 20000), sensor, 120, 24, 1);
  print("gauss s=1.5 flux=20000 (8-bit)", r);
  expect_accurate(r, 1.10);
}

TEST(Centroider, AccuracyAcrossPsfSizesAndDiscs) {
  const sim::SensorModel sensor;
  struct Case {
    double sigma, disc, flux, max_ratio;
  };
  // Gaussian spots from sharp to defocused, a faint one (peak ~17 DN, 6 sigma threshold at
  // 5 DN), then discs (retro-reflector images) with a sharp PSF, for which the Gaussian
  // template is only an approximation (docs/centroiding.md).
  for (const Case& c :
       {Case{0.8, 0, 8000, 1.10}, Case{1.0, 0, 12000, 1.10}, Case{2.0, 0, 30000, 1.10},
        Case{2.5, 0, 40000, 1.10}, Case{1.5, 0, 5000, 1.10}, Case{0.7, 2.0, 12000, 1.10},
        Case{0.7, 4.0, 20000, 1.10}, Case{1.0, 6.0, 40000, 1.10}}) {
    sim::Spot prototype = gaussian_spot(c.sigma, c.flux);
    prototype.disc_diameter_px = c.disc;
    const auto r = monte_carlo(prototype, sensor, 40, 24, 7);
    char what[64];
    std::snprintf(what, sizeof what, "psf %.1f disc %.1f flux %.0f", c.sigma, c.disc, c.flux);
    print(what, r);
    SCOPED_TRACE(what);
    expect_accurate(r, c.max_ratio);
  }
}

TEST(Centroider, Mono16PathMatchesTheBound) {
  sim::SensorModel sensor;
  sensor.bits = 12;
  sensor.full_scale_dn = 4095;
  sensor.gain_e_per_dn = 1.25;  // same ~5 ke- range as the 8-bit default
  const auto r = monte_carlo(gaussian_spot(1.5, 20000), sensor, 60, 24, 3, /*mono16=*/true);
  print("gauss s=1.5 flux=20000 (12-bit)", r);
  expect_accurate(r, 1.10);
}

// One frame with the given spots; returns the blobs.
std::vector<Blob> centroid_once(const std::vector<sim::Spot>& spots, int width = 320,
                                int height = 200, std::uint64_t seed = 5) {
  const sim::SensorModel sensor;
  std::mt19937_64 rng(seed);
  std::vector<std::uint8_t> image(width * height);
  sim::render_spots(spots, sensor, rng, image.data(), width, height, width);
  Centroider centroider(config_for(sensor), width, height);
  std::vector<Blob> blobs(64);
  const int n = centroider.process(view_of(image, width, height), blobs);
  EXPECT_GE(n, 0);
  blobs.resize(std::max(n, 0));
  return blobs;
}

const Blob* nearest(const std::vector<Blob>& blobs, double x, double y, double radius = 3) {
  const Blob* best = nullptr;
  for (const Blob& b : blobs) {
    if (std::hypot(b.x_px - x, b.y_px - y) < radius) best = &b;
  }
  return best;
}

TEST(Centroider, FlagsSaturatedBorderMergedElongated) {
  std::vector<sim::Spot> spots;
  sim::Spot clean = gaussian_spot(1.5, 20000);
  clean.x_px = 60.3, clean.y_px = 60.6;
  spots.push_back(clean);
  sim::Spot saturated = gaussian_spot(1.5, 200000);
  saturated.x_px = 140.2, saturated.y_px = 60.1;
  spots.push_back(saturated);
  sim::Spot border = gaussian_spot(1.5, 20000);
  border.x_px = 0.8, border.y_px = 120.4;
  spots.push_back(border);
  sim::Spot blurred = gaussian_spot(1.2, 30000);
  blurred.x_px = 220.5, blurred.y_px = 60.5;
  blurred.blur_dx_px = 8;
  blurred.blur_dy_px = 3;
  spots.push_back(blurred);
  sim::Spot pair_a = gaussian_spot(1.2, 20000), pair_b = pair_a;
  pair_a.x_px = 120.0, pair_a.y_px = 150.2;
  pair_b.x_px = 125.0, pair_b.y_px = 151.0;
  spots.push_back(pair_a);
  spots.push_back(pair_b);

  const auto blobs = centroid_once(spots);
  const Blob* b = nearest(blobs, clean.x_px, clean.y_px);
  ASSERT_NE(b, nullptr);
  EXPECT_EQ(b->flags, 0);
  b = nearest(blobs, saturated.x_px, saturated.y_px);
  ASSERT_NE(b, nullptr);
  EXPECT_EQ(b->flags, blob_flags::kSaturated);
  EXPECT_LT(std::hypot(b->x_px - saturated.x_px, b->y_px - saturated.y_px), 0.1);
  b = nearest(blobs, border.x_px, border.y_px, 3);
  ASSERT_NE(b, nullptr);
  EXPECT_TRUE(b->flags & blob_flags::kBorder);
  b = nearest(blobs, blurred.x_px, blurred.y_px);
  ASSERT_NE(b, nullptr);
  EXPECT_EQ(b->flags, blob_flags::kElongated);
  EXPECT_GT(b->axis_ratio, 1.5f);
  // The pair is one component with two maxima.
  b = nearest(blobs, 0.5 * (pair_a.x_px + pair_b.x_px), 0.5 * (pair_a.y_px + pair_b.y_px), 2);
  ASSERT_NE(b, nullptr);
  EXPECT_TRUE(b->flags & blob_flags::kMerged);
  EXPECT_EQ(blobs.size(), 5u);
}

TEST(Centroider, SizeAndBrightnessAreReported) {
  sim::Spot spot = gaussian_spot(1.5, 20000);
  spot.x_px = 100.4, spot.y_px = 80.3;
  const sim::SensorModel sensor;
  const auto blobs = centroid_once({spot});
  ASSERT_EQ(blobs.size(), 1u);
  const Blob& b = blobs[0];
  // Flux over the refinement patch (+-4 sigma) holds essentially all of the spot's signal.
  EXPECT_NEAR(b.flux_dn, spot.flux_e / sensor.gain_e_per_dn,
              0.05 * spot.flux_e / sensor.gain_e_per_dn);
  sim::SpotRenderer renderer;
  const auto st = renderer.statistics(spot, sensor, 320, 200);
  EXPECT_NEAR(b.peak_dn, st.peak_signal_e / sensor.gain_e_per_dn, 5.0);
  EXPECT_NEAR(b.background_dn, sensor.background_e / sensor.gain_e_per_dn, 0.2);
  EXPECT_NEAR(b.diameter_px, std::sqrt(4 * b.area_px / M_PI), 1e-4);
  EXPECT_LT(b.axis_ratio, 1.3f);
  EXPECT_GT(b.sigma_px, 0.0);
}

TEST(Centroider, FollowsABackgroundGradient) {
  // A smooth illumination gradient (0..30 DN across the frame) on top of the sensor background:
  // the tile background must follow it so that thresholds, fluxes and centroids do not.
  constexpr int kW = 640, kH = 320;
  const sim::SensorModel sensor;
  std::mt19937_64 rng(17);
  sim::SpotRenderer renderer;
  std::vector<std::uint8_t> image(kW * kH);
  Centroider centroider(config_for(sensor), kW, kH);
  std::vector<Blob> blobs(64);
  eval::ErrorStats errors;
  auto ramp = [](double x, double y) { return 20.0 * x / kW + 10.0 * y / kH; };
  for (int frame = 0; frame < 20; ++frame) {
    const auto spots = eval::random_spots(gaussian_spot(1.5, 20000), 24, kW, kH, 24, 24, rng);
    renderer.render(spots, sensor, rng, image.data(), kW, kH, kW);
    for (int y = 0; y < kH; ++y)
      for (int x = 0; x < kW; ++x)
        image[y * kW + x] =
            static_cast<std::uint8_t>(std::min(255.0, image[y * kW + x] + std::round(ramp(x, y))));
    const int n = centroider.process(view_of(image, kW, kH), blobs);
    ASSERT_EQ(n, 24);
    for (const eval::Match& m : eval::match(spots, std::span(blobs.data(), n), 3.0)) {
      ASSERT_GE(m.blob, 0);
      const Blob& b = blobs[m.blob];
      EXPECT_EQ(b.flags, 0);
      EXPECT_NEAR(b.background_dn,
                  sensor.background_e / sensor.gain_e_per_dn + ramp(b.x_px, b.y_px), 0.6);
      errors.add(m.error_x_px, m.error_y_px, b.sigma_px, 0);
    }
  }
  EXPECT_LT(std::abs(errors.bias_x()), 0.01);
  EXPECT_LT(std::abs(errors.bias_y()), 0.01);
  // The gradient adds a little photon noise; the prediction must follow the observed spread.
  EXPECT_NEAR(errors.rms_predicted() / errors.rms(), 1.0, 0.15);
}

TEST(Centroider, RegionsOfInterestLimitTheSearch) {
  constexpr int kW = 320, kH = 200;
  std::vector<sim::Spot> spots;
  for (int k = 0; k < 4; ++k) {
    sim::Spot s = gaussian_spot(1.5, 20000);
    s.x_px = 40.3 + 70 * k;
    s.y_px = 100.6;
    spots.push_back(s);
  }
  const sim::SensorModel sensor;
  std::mt19937_64 rng(11);
  std::vector<std::uint8_t> image(kW * kH);
  sim::render_spots(spots, sensor, rng, image.data(), kW, kH, kW);
  Centroider centroider(config_for(sensor), kW, kH);
  std::vector<Blob> blobs(16);
  // ROI around spot 1 (fully inside) and one cutting spot 3 in half.
  const std::vector<Roi> rois = {{static_cast<int>(spots[1].x_px) - 15, 85, 30, 30},
                                 {static_cast<int>(spots[3].x_px), 85, 30, 30}};
  const int n = centroider.process(view_of(image, kW, kH), rois, blobs);
  ASSERT_EQ(n, 2);
  const std::vector<Blob> found(blobs.begin(), blobs.begin() + n);
  const Blob* inside = nearest(found, spots[1].x_px, spots[1].y_px, 0.3);
  ASSERT_NE(inside, nullptr);
  EXPECT_EQ(inside->flags, 0);
  const Blob* cut = nearest(found, spots[3].x_px, spots[3].y_px, 3);
  ASSERT_NE(cut, nullptr);
  EXPECT_TRUE(cut->flags & blob_flags::kBorder);
  // Out-of-frame and empty ROIs are clipped away, not errors.
  const std::vector<Roi> outside = {{-100, -100, 50, 50}, {kW + 5, 0, 10, 10}};
  EXPECT_EQ(centroider.process(view_of(image, kW, kH), outside, blobs), 0);
}

TEST(Centroider, DoesNotAllocatePerFrame) {
  constexpr int kW = 1920, kH = 1024;
  const sim::SensorModel sensor;
  std::mt19937_64 rng(21);
  const auto spots = eval::random_spots(gaussian_spot(1.5, 20000), 64, kW, kH, 20, 20, rng);
  std::vector<std::uint8_t> image(kW * kH);
  sim::render_spots(spots, sensor, rng, image.data(), kW, kH, kW);
  Centroider centroider(config_for(sensor), kW, kH);
  std::vector<Blob> blobs(64);
  const std::vector<Roi> rois = {{100, 100, 200, 200}};
  const long before = storetrack::testing::allocation_count();
  int n = 0;
  for (int i = 0; i < 5; ++i) {
    n = centroider.process(view_of(image, kW, kH), blobs);
    centroider.process(view_of(image, kW, kH), rois, blobs);
  }
  EXPECT_EQ(storetrack::testing::allocation_count(), before);
  EXPECT_EQ(n, 64);
}

TEST(Centroider, KeepsTheBrightestWhenTheOutputIsFull) {
  std::vector<sim::Spot> spots;
  for (int k = 0; k < 6; ++k) {
    sim::Spot s = gaussian_spot(1.5, 8000 + 2000 * k);
    s.x_px = 30.5 + 45 * k;
    s.y_px = 60.2;
    spots.push_back(s);
  }
  const sim::SensorModel sensor;
  std::mt19937_64 rng(4);
  std::vector<std::uint8_t> image(320 * 200);
  sim::render_spots(spots, sensor, rng, image.data(), 320, 200, 320);
  Centroider centroider(config_for(sensor), 320, 200);
  std::vector<Blob> blobs(3);
  ASSERT_EQ(centroider.process(view_of(image, 320, 200), blobs), 3);
  EXPECT_EQ(centroider.stats().blobs_truncated, 3u);
  for (const Blob& b : blobs)
    EXPECT_GT(b.x_px, spots[2].x_px + 10);  // the three brightest
}

TEST(Centroider, RefusesBadFramesAndOverflowWithCounters) {
  const sim::SensorModel sensor;
  CentroidConfig config = config_for(sensor);
  Centroider centroider(config, 64, 32);
  std::vector<Blob> blobs(8);
  std::vector<std::uint8_t> image(128 * 64, 5);
  FrameView f = view_of(image, 128, 64);  // larger than max
  EXPECT_EQ(centroider.process(f, blobs), -EINVAL);
  f = view_of(image, 64, 32);
  f.pixels = nullptr;
  EXPECT_EQ(centroider.process(f, blobs), -EINVAL);
  f = view_of(image, 64, 32);
  f.stride_bytes = 10;
  EXPECT_EQ(centroider.process(f, blobs), -EINVAL);
  f = view_of(image, 64, 32);
  f.format = PixelFormat::kMono16;  // bits_per_pixel 8 does not fit Mono16
  EXPECT_EQ(centroider.process(f, blobs), -EINVAL);
  EXPECT_EQ(centroider.stats().frames_refused, 4u);

  // Isolated bright pixels (odd columns of even rows) make more runs than max_runs.
  config.max_runs = 16;
  Centroider small(config, 64, 32);
  for (int y = 0; y < 32; ++y)
    for (int x = 0; x < 64; ++x)
      image[y * 64 + x] = (x % 2 == 1 && y % 2 == 0) ? 200 : 5;
  EXPECT_EQ(small.process(view_of(image, 64, 32), blobs), -EOVERFLOW);
  EXPECT_EQ(small.stats().run_overflows, 1u);

  CentroidConfig bad = config;
  bad.gain_e_per_dn = 0;
  EXPECT_THROW(Centroider(bad, 64, 32), std::invalid_argument);
}

}  // namespace
}  // namespace storetrack::centroid
