// storetrack-centroid-bench: time per frame and accuracy against simulator truth of the unit's
// centroider and its peers, in one run on one core (docs/performance.md, ## Centroiding).
//
// Peers:
//  - OpenCV threshold + connectedComponentsWithStats + background-subtracted weighted moments
//    over each component's labelled pixels;
//  - OpenCV threshold + findContours + intensity-weighted moments over each contour's bounding
//    box padded by --pad px (the fastest accurate OpenCV pipeline);
//  - SEP 1.2 (libsep): sep_background + sep_extract + sep_flux_radius + sep_windowed (XWIN with
//    sigma = 2 r_half / 2.35, the SEP documentation's recipe);
//  - memcpy of the frame and one cv::threshold pass (the physical floor).
// OpenCV peers are handed the true background level and the same threshold (favourable to them).
#include <sched.h>

extern "C" {  // sep.h has no C++ guard
#include <sep.h>
}

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <string>
#include <vector>
#include "storetrack/cli/command_line.hpp"

#include "centroid_eval.hpp"
#include "storetrack/centroid/centroider.hpp"
#include "storetrack/sim/render.hpp"

namespace {

using storetrack::centroid::Blob;
namespace sim = storetrack::sim;
namespace eval = storetrack::centroid::eval;

constexpr int kWidth = 1920, kHeight = 1024;

struct Frame {
  std::vector<std::uint8_t> pixels;
  std::vector<sim::Spot> truth;
  std::vector<double> crb_sigma;  // per truth spot
};

struct Method {
  std::string name;
  bool accuracy = true;  // false: floor passes (no positions)
  bool slow = false;     // timed in the first round only
  std::function<int(const Frame&, std::vector<Blob>&)> run;
};

struct Result {
  double median_us = 0, best_us = 0;
  eval::ErrorStats errors;
  int false_detections = 0;
};

// Weighted moments of (I - b) over a rectangle, optionally restricted to one label.
Blob weighted_moments(const cv::Mat& image, const cv::Rect& box, double background,
                      const cv::Mat* labels = nullptr, int label = 0) {
  double s = 0, sx = 0, sy = 0;
  for (int y = box.y; y < box.y + box.height; ++y) {
    const std::uint8_t* row = image.ptr<std::uint8_t>(y);
    const int* lrow = labels ? labels->ptr<int>(y) : nullptr;
    for (int x = box.x; x < box.x + box.width; ++x) {
      if (lrow && lrow[x] != label) continue;
      const double w = row[x] - background;
      s += w;
      sx += w * x;
      sy += w * y;
    }
  }
  Blob b;
  if (s > 0) {
    b.x_px = sx / s;
    b.y_px = sy / s;
  } else {
    b.x_px = b.y_px = -1e9;
  }
  return b;
}

}  // namespace

int main(int argc, char** argv) {
  storetrack::cli::Command app{
      "storetrack centroiding benchmark (one core, simulated 1920x1024 frames)"};
  int frames_per_set = 8;
  double min_time_s = 1.0;
  double psf_sigma = 1.5, disc = 0.0, flux = 20000;
  int pad = 2;
  std::uint64_t seed = 1;
  std::vector<int> mark_counts = {16, 64};
  app.option("--frames", frames_per_set, "distinct frames per mark count").range(1, 256);
  app.option("--min-time", min_time_s, "minimum timing per method and mark count [s]");
  app.option("--sigma", psf_sigma, "PSF sigma [px]");
  app.option("--disc", disc, "disc diameter [px]");
  app.option("--flux", flux, "flux per mark [e-]");
  app.option("--pad", pad, "padding of the findContours boxes [px]");
  app.option("--marks", mark_counts, "mark counts per frame");
  app.option("--seed", seed, "random seed");
  if (const int rc = app.parse(argc, argv); rc >= 0) return rc;

  // One core: pin the process and keep OpenCV single-threaded.
  cpu_set_t cpus;
  CPU_ZERO(&cpus);
  CPU_SET(0, &cpus);
  const bool pinned = sched_setaffinity(0, sizeof cpus, &cpus) == 0;
  cv::setNumThreads(1);

  const sim::SensorModel sensor;  // the simulator's default 8-bit camera
  const double background_dn = sensor.background_e / sensor.gain_e_per_dn;
  storetrack::centroid::CentroidConfig config;
  config.read_noise_e = sensor.read_noise_e;
  config.gain_e_per_dn = sensor.gain_e_per_dn;
  config.black_level_dn = sensor.black_level_dn;
  config.saturation_dn = sensor.full_scale_dn;
  storetrack::centroid::Centroider centroider(config, kWidth, kHeight);
  storetrack::centroid::CentroidConfig windowed_config = config;
  windowed_config.photon_weighting = false;
  storetrack::centroid::Centroider windowed_only(windowed_config, kWidth, kHeight);
  storetrack::centroid::CentroidConfig threshold_only_config = config;
  threshold_only_config.refine = false;
  storetrack::centroid::Centroider moments_only(threshold_only_config, kWidth, kHeight);
  // Same absolute level for the OpenCV peers as the centroider's default (6 sigma).
  const double noise_dn =
      std::sqrt((sensor.background_e + sensor.read_noise_e * sensor.read_noise_e) /
                    (sensor.gain_e_per_dn * sensor.gain_e_per_dn) +
                1.0 / 12.0);
  const double level = std::floor(background_dn + config.threshold_sigma * noise_dn);

  std::printf("# storetrack-centroid-bench\n\n");
  std::printf(
      "Frames %dx%d Mono8, %d distinct frames per set, marks: Gaussian PSF sigma %.2f px, disc "
      "%.1f px, %.0f e- each; sensor: background %.0f e-, read noise %.0f e-, gain %.0f e-/DN. "
      "One core (%s), OpenCV threads 1, SEP %s.\n\n",
      kWidth, kHeight, frames_per_set, psf_sigma, disc, flux, sensor.background_e,
      sensor.read_noise_e, sensor.gain_e_per_dn, pinned ? "pinned to CPU 0" : "not pinned",
      sep_version_string);

  cv::Mat binary(kHeight, kWidth, CV_8U), labels, stats, centroids, copy(kHeight, kWidth, CV_8U);
  std::vector<std::vector<cv::Point>> contours;
  std::vector<float> sep_data(static_cast<size_t>(kWidth) * kHeight);

  std::vector<Method> methods;
  methods.push_back({"storetrack centroider (default: windowed + ML weighting)", true, false,
                     [&](const Frame& f, std::vector<Blob>& out) {
                       storetrack::frame::FrameView v;
                       v.pixels = f.pixels.data();
                       v.width = kWidth;
                       v.height = kHeight;
                       v.stride_bytes = kWidth;
                       return centroider.process(v, out);
                     }});
  methods.push_back({"storetrack, Gaussian-windowed only", true, false,
                     [&](const Frame& f, std::vector<Blob>& out) {
                       storetrack::frame::FrameView v;
                       v.pixels = f.pixels.data();
                       v.width = kWidth;
                       v.height = kHeight;
                       v.stride_bytes = kWidth;
                       return windowed_only.process(v, out);
                     }});
  methods.push_back({"storetrack, threshold moments only", true, false,
                     [&](const Frame& f, std::vector<Blob>& out) {
                       storetrack::frame::FrameView v;
                       v.pixels = f.pixels.data();
                       v.width = kWidth;
                       v.height = kHeight;
                       v.stride_bytes = kWidth;
                       return moments_only.process(v, out);
                     }});
  methods.push_back(
      {"OpenCV threshold + connectedComponentsWithStats + moments", true, true,
       [&](const Frame& f, std::vector<Blob>& out) {
         const cv::Mat image(kHeight, kWidth, CV_8U, const_cast<std::uint8_t*>(f.pixels.data()));
         cv::threshold(image, binary, level, 255, cv::THRESH_BINARY);
         const int n =
             cv::connectedComponentsWithStats(binary, labels, stats, centroids, 8, CV_32S);
         int count = 0;
         for (int i = 1; i < n && count < static_cast<int>(out.size()); ++i) {
           if (stats.at<int>(i, cv::CC_STAT_AREA) < config.min_area_px) continue;
           const cv::Rect box(stats.at<int>(i, cv::CC_STAT_LEFT), stats.at<int>(i, cv::CC_STAT_TOP),
                              stats.at<int>(i, cv::CC_STAT_WIDTH),
                              stats.at<int>(i, cv::CC_STAT_HEIGHT));
           out[count++] = weighted_moments(image, box, background_dn, &labels, i);
         }
         return count;
       }});
  methods.push_back(
      {"OpenCV threshold + findContours + padded-box moments", true, false,
       [&](const Frame& f, std::vector<Blob>& out) {
         const cv::Mat image(kHeight, kWidth, CV_8U, const_cast<std::uint8_t*>(f.pixels.data()));
         cv::threshold(image, binary, level, 255, cv::THRESH_BINARY);
         cv::findContours(binary, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
         int count = 0;
         const cv::Rect frame_rect(0, 0, kWidth, kHeight);
         for (const auto& contour : contours) {
           if (count >= static_cast<int>(out.size())) break;
           cv::Rect box = cv::boundingRect(contour);
           if (box.area() < config.min_area_px) continue;
           box = cv::Rect(box.x - pad, box.y - pad, box.width + 2 * pad, box.height + 2 * pad) &
                 frame_rect;
           out[count++] = weighted_moments(image, box, background_dn);
         }
         return count;
       }});
  methods.push_back({"SEP background + extract + windowed (XWIN)", true, true,
                     [&](const Frame& f, std::vector<Blob>& out) {
                       for (size_t i = 0; i < sep_data.size(); ++i)
                         sep_data[i] = f.pixels[i];
                       sep_image im{};
                       im.data = sep_data.data();
                       im.dtype = SEP_TFLOAT;
                       im.w = kWidth;
                       im.h = kHeight;
                       im.noise_type = SEP_NOISE_NONE;
                       sep_bkg* bkg = nullptr;
                       if (sep_background(&im, 64, 64, 3, 3, 0.0, &bkg) != 0) return -1;
                       const float rms = sep_bkg_globalrms(bkg);
                       sep_bkg_subarray(bkg, sep_data.data(), SEP_TFLOAT);
                       sep_bkg_free(bkg);
                       static const float kConv[9] = {1, 2, 1, 2, 4, 2, 1, 2, 1};
                       sep_catalog* cat = nullptr;
                       // 6 sigma above the (per-pixel) background rms, on the 3x3-filtered image.
                       if (sep_extract(&im, 6.0f * rms, SEP_THRESH_ABS, 5, kConv, 3, 3,
                                       SEP_FILTER_CONV, 32, 0.005, 1, 1.0, &cat) != 0)
                         return -1;
                       int count = 0;
                       for (int i = 0; i < cat->nobj && count < static_cast<int>(out.size()); ++i) {
                         const double frac = 0.5, total = cat->flux[i];
                         double r_half = 0;
                         short flag = 0;
                         sep_flux_radius(&im, cat->x[i], cat->y[i], 6.0 * cat->a[i], 0, 5, 0,
                                         &total, &frac, 1, &r_half, &flag);
                         double xw = cat->x[i], yw = cat->y[i];
                         int niter = 0;
                         sep_windowed(&im, cat->x[i], cat->y[i], 2.0 / 2.35 * r_half, 11, 0, &xw,
                                      &yw, &niter, &flag);
                         Blob b;
                         b.x_px = xw;
                         b.y_px = yw;
                         out[count++] = b;
                       }
                       sep_catalog_free(cat);
                       return count;
                     }});
  methods.push_back(
      {"memcpy of the frame (floor)", false, false, [&](const Frame& f, std::vector<Blob>&) {
         std::memcpy(copy.data, f.pixels.data(), f.pixels.size());
         return 0;
       }});
  methods.push_back(
      {"cv::threshold pass only (floor)", false, false, [&](const Frame& f, std::vector<Blob>&) {
         const cv::Mat image(kHeight, kWidth, CV_8U, const_cast<std::uint8_t*>(f.pixels.data()));
         cv::threshold(image, binary, level, 255, cv::THRESH_BINARY);
         return 0;
       }});

  std::mt19937_64 rng(seed);
  sim::SpotRenderer renderer;
  for (const int marks : mark_counts) {
    sim::Spot prototype;
    prototype.psf_sigma_px = psf_sigma;
    prototype.disc_diameter_px = disc;
    prototype.flux_e = flux;
    std::vector<Frame> frames(frames_per_set);
    for (Frame& f : frames) {
      f.truth = eval::random_spots(prototype, marks, kWidth, kHeight, 24, 24, rng);
      f.pixels.resize(static_cast<size_t>(kWidth) * kHeight);
      renderer.render(f.truth, sensor, rng, f.pixels.data(), kWidth, kHeight, kWidth);
      for (const sim::Spot& s : f.truth)
        f.crb_sigma.push_back(eval::cramer_rao(renderer, s, sensor, kWidth, kHeight).sigma_px);
    }
    std::vector<Result> results(methods.size());
    std::vector<Blob> blobs(256);
    // Accuracy from one pass over the frames.
    for (size_t m = 0; m < methods.size(); ++m) {
      if (!methods[m].accuracy) continue;
      for (const Frame& f : frames) {
        const int n = methods[m].run(f, blobs);
        const auto matches = eval::match(f.truth, std::span(blobs.data(), std::max(n, 0)), 2.0);
        int matched = 0;
        for (const auto& match : matches) {
          if (match.blob < 0) {
            ++results[m].errors.missed;
            continue;
          }
          ++matched;
          results[m].errors.add(match.error_x_px, match.error_y_px, 0, f.crb_sigma[match.truth]);
        }
        results[m].false_detections += std::max(n, 0) - matched;
      }
    }
    // Timing: round robin over the methods frame by frame, so that load from other processes
    // on the machine hits all methods alike; the slow ones (SEP, connectedComponents) only in
    // the first round.
    std::vector<std::vector<double>> times_us(methods.size());
    std::vector<std::uint8_t> evict(16u << 20);  // 16 MiB > L2 of this machine (2 MiB/core)
    const auto start = std::chrono::steady_clock::now();
    for (int round = 0;; ++round) {
      for (const Frame& f : frames) {
        for (size_t m = 0; m < methods.size(); ++m) {
          if (round > 0 && methods[m].slow) continue;
          // Every method starts with the frame out of the core's L1/L2 (a freshly captured
          // frame is not there either); otherwise whichever method runs first in the round
          // pays the memory traffic for the others.
          for (size_t k = 0; k < evict.size(); k += 64)
            evict[k] = static_cast<std::uint8_t>(k + round);
          const auto t0 = std::chrono::steady_clock::now();
          methods[m].run(f, blobs);
          const auto t1 = std::chrono::steady_clock::now();
          times_us[m].push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
        }
      }
      if (std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() >=
          min_time_s)
        break;
    }
    for (size_t m = 0; m < methods.size(); ++m) {
      auto& t = times_us[m];
      std::sort(t.begin(), t.end());
      results[m].median_us = t[t.size() / 2];
      results[m].best_us = t.front();
    }

    const double ours = results[0].median_us;
    const double contours_us = results[4].median_us;
    const double threshold_us = results[7].median_us;
    std::printf("## %d marks per frame\n\n", marks);
    std::printf(
        "| method | median ms/frame | best ms/frame | frames/s (median) | time vs storetrack "
        "(median, best) | RMS error px (per axis) | RMS / CRB | bias x, y px | missed | extra |\n");
    std::printf("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for (size_t m = 0; m < methods.size(); ++m) {
      const Result& r = results[m];
      std::printf("| %s | %.4f | %.4f | %.0f | %.2fx, %.2fx |", methods[m].name.c_str(),
                  r.median_us / 1000.0, r.best_us / 1000.0, 1e6 / r.median_us, r.median_us / ours,
                  r.best_us / results[0].best_us);
      if (methods[m].accuracy) {
        std::printf(" %.4f | %.3f | %+.4f, %+.4f | %d | %d |\n", r.errors.rms(),
                    r.errors.ratio_to_crb(), r.errors.bias_x(), r.errors.bias_y(), r.errors.missed,
                    r.false_detections);
      } else {
        std::printf(" - | - | - | - | - |\n");
      }
    }
    const Result& best_ours = results[0];
    std::printf(
        "\nCramer-Rao bound (RMS over the marks): %.4f px. storetrack (median; best): %.2fx; %.2fx "
        "the throughput of findContours + moments, %.2fx; %.2fx the time of the threshold-only "
        "pass, %.2fx; %.2fx a memcpy.\n\n",
        results[0].errors.rms_crb(), contours_us / ours, results[4].best_us / best_ours.best_us,
        ours / threshold_us, best_ours.best_us / results[7].best_us, ours / results[6].median_us,
        best_ours.best_us / results[6].best_us);
  }
  return 0;
}
