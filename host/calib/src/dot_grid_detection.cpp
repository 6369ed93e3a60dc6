// Dot grids measured with the unit's centroider (estimation/centroid, the flight marks' code and
// sigma), indexed into the grid model (docs/calibration.md, "Dot grids").
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>

#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>

#include "dot_indexing.hpp"
#include "image_set_check.hpp"
#include "storetrack/calib/dot_grid_detection.hpp"
#include "storetrack/centroid/centroider.hpp"

namespace storetrack::calib {
namespace {

using dots::MeasuredDot;

/// Dots smaller / larger than these multiples of the image's median dot area are not dots.
constexpr double kMinAreaRatio = 0.4, kMaxAreaRatio = 4.0;
/// A ring dot is dot-sized (its hole takes ~10 % of the area) and as contrasted as a dot: a
/// faint blob with a dark middle (a smudge, a shadow) is not taken for a marker.
constexpr double kRingMinAreaRatio = 0.6, kRingMinPeakRatio = 0.5;
/// The smallest blob that can be a calibration dot in the first (sizing) pass [px].
constexpr int kSizingMinAreaPx = 20;
/// Background tiles span this many dot diameters, so one tile's median is the paper's level
/// (a dot covers <= 1/(4 * 3^2 / pi) = 9 % of a tile, a grid with spacing >= 2 diameters <= 20 %).
constexpr double kTileDiameters = 3.0;
/// A ring dot's centre (this fraction of its diameter in radius) is darker than half its peak.
constexpr double kRingProbeRadius = 0.08;
constexpr int kMaxBlobs = 4096;
/// Components the centroider keeps per frame (in raster order): paper texture and JPEG noise
/// above the first pass's noise-model threshold must not use them all up.
constexpr int kMaxCandidates = 1 << 16;
/// The second pass thresholds at this fraction of the median dot's contrast (the edge's half
/// level: the dot's own outline, far above paper texture).
constexpr double kThresholdOfPeak = 0.5;

centroid::CentroidConfig dot_config(const DotCentroidOptions& o) {
  centroid::CentroidConfig c;
  c.gain_e_per_dn = o.gain_e_per_dn;
  c.read_noise_e = o.read_noise_e;
  c.threshold_sigma = o.threshold_sigma;
  c.max_area_px = std::numeric_limits<int>::max() / 4;  // size is judged against the median
  c.max_window_half_px = 64;                            // the centroider's largest patch
  c.max_candidates = kMaxCandidates;
  c.max_runs = 1 << 20;
  return c;
}

std::vector<centroid::Blob> centroid_frame(const centroid::CentroidConfig& config,
                                           const frame::FrameView& frame) {
  centroid::Centroider centroider(config, frame.width, frame.height);
  std::vector<centroid::Blob> blobs(kMaxBlobs);
  const int n = centroider.process(frame, blobs);
  blobs.resize(static_cast<size_t>(std::max(n, 0)));
  return blobs;
}

template <class Field>
double median_of(const std::vector<centroid::Blob>& blobs, Field field) {
  std::vector<double> v;
  for (const centroid::Blob& b : blobs)
    v.push_back(field(b));
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

double median_area(const std::vector<centroid::Blob>& blobs) {
  return median_of(blobs, [](const centroid::Blob& b) { return b.area_px; });
}

double median_peak(const std::vector<centroid::Blob>& blobs) {
  return median_of(blobs, [](const centroid::Blob& b) { return b.peak_dn; });
}

/// The first pass's dots: its blobs at least a quarter of the 90th-percentile area (the
/// population of equal dots, without texture specks).
std::vector<centroid::Blob> dot_population(std::vector<centroid::Blob> blobs) {
  if (blobs.empty()) return blobs;
  std::sort(blobs.begin(), blobs.end(),
            [](const auto& a, const auto& b) { return a.area_px > b.area_px; });
  const double large = blobs[blobs.size() / 10].area_px;
  blobs.erase(std::remove_if(blobs.begin(), blobs.end(),
                             [&](const auto& b) { return b.area_px < 0.25 * large; }),
              blobs.end());
  return blobs;
}

/// Mean of the (inverted) image minus background in a small disc at the blob's centre.
double centre_level(const frame::FrameView& f, const centroid::Blob& b) {
  const double r = std::max(1.0, kRingProbeRadius * b.diameter_px);
  double sum = 0;
  int n = 0;
  for (int y = static_cast<int>(std::floor(b.y_px - r)); y <= static_cast<int>(b.y_px + r); ++y)
    for (int x = static_cast<int>(std::floor(b.x_px - r)); x <= static_cast<int>(b.x_px + r); ++x) {
      if (x < 0 || y < 0 || x >= f.width || y >= f.height) continue;
      if ((x - b.x_px) * (x - b.x_px) + (y - b.y_px) * (y - b.y_px) > r * r) continue;
      sum += f.pixels[static_cast<size_t>(y) * static_cast<size_t>(f.stride_bytes) +
                      static_cast<size_t>(x)];
      ++n;
    }
  return n > 0 ? sum / n - b.background_dn : 0;
}

std::string fmt1(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f", v);
  return buf;
}

struct ImageDots {
  std::vector<MeasuredDot> dots;
  std::vector<RejectedDot> rejected;
};

/// The centroider's dots of one image: bright dots on dark (the image inverted first if the
/// dots are dark), sized and thresholded from a first pass; every blob the centroider reports
/// (>= a tenth of the median dot area) that is not kept is listed with its reason.
ImageDots measure_dots(const GrayImageView& image, bool dark_dots,
                       const DotCentroidOptions& options) {
  std::vector<std::uint8_t> bright(static_cast<size_t>(image.width) * image.height);
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      const std::uint8_t v = image.pixels[static_cast<size_t>(y) * image.stride + x];
      bright[static_cast<size_t>(y) * image.width + x] =
          dark_dots ? static_cast<std::uint8_t>(255 - v) : v;
    }
  frame::FrameView frame;
  frame.pixels = bright.data();
  frame.width = image.width;
  frame.height = image.height;
  frame.stride_bytes = image.width;

  centroid::CentroidConfig config = dot_config(options);
  config.min_area_px = kSizingMinAreaPx;
  const std::vector<centroid::Blob> first = dot_population(centroid_frame(config, frame));
  const double sizing_area = median_area(first);
  ImageDots out;
  if (sizing_area <= 0) return out;
  config.threshold_dn = std::max(1, static_cast<int>(kThresholdOfPeak * median_peak(first)));
  const double diameter = std::sqrt(4 * sizing_area / M_PI);
  config.background_tile_px = std::max(128, static_cast<int>(kTileDiameters * diameter));
  config.min_area_px = std::max(3, static_cast<int>(kMinAreaRatio * sizing_area / 4));
  const std::vector<centroid::Blob> blobs = centroid_frame(config, frame);
  const double area = median_area(blobs);
  const double peak = median_peak(blobs);
  for (const centroid::Blob& b : blobs) {
    RejectedDot r{image.name, {b.x_px, b.y_px}, ""};
    if (b.flags & centroid::blob_flags::kBorder)
      r.reason = "at the image edge (the dot or its refinement window is cut: biased centroid)";
    else if (b.area_px < kMinAreaRatio * area)
      r.reason = "area " + fmt1(b.area_px) + " px, below " + fmt1(kMinAreaRatio) +
                 " x the median dot's " + fmt1(area) + " px (noise, dirt)";
    else if (b.area_px > kMaxAreaRatio * area)
      r.reason = "area " + fmt1(b.area_px) + " px, above " + fmt1(kMaxAreaRatio) +
                 " x the median dot's " + fmt1(area) + " px (merged dots, shadow, reflection)";
    if (!r.reason.empty()) {
      out.rejected.push_back(r);
      continue;
    }
    const bool ring = centre_level(frame, b) < 0.5 * b.peak_dn &&
                      b.area_px >= kRingMinAreaRatio * area &&
                      b.peak_dn >= kRingMinPeakRatio * peak;
    out.dots.push_back({{b.x_px, b.y_px}, b.sigma_px, ring});
  }
  return out;
}

/// The centroider's dots handed to findCirclesGrid as its blob detector's keypoints.
class FixedKeypoints : public cv::Feature2D {
 public:
  explicit FixedKeypoints(std::vector<cv::KeyPoint> keypoints) : keypoints_(std::move(keypoints)) {}
  void detect(cv::InputArray, std::vector<cv::KeyPoint>& keypoints, cv::InputArray) override {
    keypoints = keypoints_;
  }

 private:
  std::vector<cv::KeyPoint> keypoints_;
};

dots::GridIndexing index_full_grid(const GrayImageView& image, const std::vector<MeasuredDot>& dots,
                                   const DotGridSpec& board) {
  dots::GridIndexing out;
  std::vector<cv::KeyPoint> keypoints;
  for (const MeasuredDot& d : dots)
    keypoints.emplace_back(static_cast<float>(d.pixel.x()), static_cast<float>(d.pixel.y()), 10.f);
  const cv::Mat gray(image.height, image.width, CV_8UC1, const_cast<std::uint8_t*>(image.pixels),
                     static_cast<size_t>(image.stride));
  std::vector<cv::Point2f> centres;
  if (!cv::findCirclesGrid(gray, cv::Size(board.cols, board.rows), centres,
                           cv::CALIB_CB_SYMMETRIC_GRID, cv::makePtr<FixedKeypoints>(keypoints))) {
    out.failure = "no " + std::to_string(board.cols) + "x" + std::to_string(board.rows) +
                  " dot grid among the " + std::to_string(dots.size()) +
                  " dots (the whole grid must be in view; --board ring-dots indexes a grid "
                  "larger than the view)";
    return out;
  }
  std::vector<bool> used(dots.size(), false);
  for (size_t i = 0; i < centres.size(); ++i) {
    // findCirclesGrid returns its keypoints' positions: find the dot each one came from.
    size_t best = 0;
    double best_d = std::numeric_limits<double>::infinity();
    for (size_t k = 0; k < dots.size(); ++k) {
      const double d =
          std::hypot(dots[k].pixel.x() - centres[i].x, dots[k].pixel.y() - centres[i].y);
      if (d < best_d) best_d = d, best = k;
    }
    if (best_d > 1e-3 || used[best]) {
      out.failure = "findCirclesGrid returned a point that is not one of the dots";
      return out;
    }
    used[best] = true;
    out.indexed.push_back({static_cast<int>(best), static_cast<int>(i) % board.cols,
                           static_cast<int>(i) / board.cols});
  }
  for (size_t k = 0; k < dots.size(); ++k)
    if (!used[k]) out.unindexed.emplace_back(static_cast<int>(k), "not part of the grid found");
  return out;
}

Eigen::Vector3d board_point(const DotGridSpec& board, int col, int row) {
  if (board.kind == DotBoardKind::kDots) return {col * board.spacing_m, row * board.spacing_m, 0};
  return {(col - board.origin_col) * board.spacing_m, (row - board.origin_row) * board.spacing_m,
          0};
}

/// One image into `out` as frame `frame` (or a rejection with its reason).
void detect_one(const GrayImageView& image, int frame, const DotGridSpec& board,
                const DotCentroidOptions& options, int camera, DotDetectionResult& out) {
  ImageDots measured = measure_dots(image, board.dark_dots, options);
  out.rejected_dots.insert(out.rejected_dots.end(), measured.rejected.begin(),
                           measured.rejected.end());
  if (measured.dots.size() < 4) {
    out.rejected.push_back({image.name, "only " + std::to_string(measured.dots.size()) +
                                            " dots found by the centroider (need >= 4)"});
    return;
  }
  const dots::GridIndexing grid = board.kind == DotBoardKind::kDots
                                      ? index_full_grid(image, measured.dots, board)
                                      : dots::index_ring_dot_grid(measured.dots, board);
  if (!grid.failure.empty()) {
    out.rejected.push_back({image.name, grid.failure});
    return;
  }
  for (const auto& [dot, reason] : grid.unindexed)
    out.rejected_dots.push_back(
        {image.name, measured.dots[static_cast<size_t>(dot)].pixel, reason});
  if (grid.indexed.size() < 4) {
    out.rejected.push_back(
        {image.name, "only " + std::to_string(grid.indexed.size()) + " dots indexed (need >= 4)"});
    return;
  }
  for (const dots::IndexedDot& d : grid.indexed) {
    const MeasuredDot& m = measured.dots[static_cast<size_t>(d.dot)];
    Observation o;
    o.camera = camera;
    o.frame = frame;
    o.point_id = d.row * board.cols + d.col;
    o.p_board = board_point(board, d.col, d.row);
    o.pixel = m.pixel;
    if (m.sigma_px > 0) o.sigma_px = m.sigma_px;
    out.set.observations.push_back(o);
  }
  std::sort(out.set.observations.end() - static_cast<std::ptrdiff_t>(grid.indexed.size()),
            out.set.observations.end(),
            [](const Observation& a, const Observation& b) { return a.point_id < b.point_id; });
  out.set.frame_sources[frame] = image.name;
  if (board.kind == DotBoardKind::kRingDots) out.markers.emplace_back(frame, grid.markers);
  ++out.images_used;
}

void check_spec(const DotGridSpec& board) {
  if (board.cols < 2 || board.rows < 2 || !(board.spacing_m > 0))
    throw std::invalid_argument("dot grid: cols and rows must be >= 2, spacing > 0");
  if (board.kind == DotBoardKind::kRingDots &&
      (board.origin_to_x_marker < 2 || board.origin_to_y_marker < 2 ||
       board.origin_col + board.origin_to_x_marker > board.cols ||
       board.origin_row + board.origin_to_y_marker > board.rows || board.origin_col < 0 ||
       board.origin_row < 0))
    throw std::invalid_argument(
        "dot grid: the ring-dot markers (origin, origin-to-x, origin-to-y) must lie in the "
        "cols x rows grid, each marker >= 2 dots from the origin (counting the origin)");
}

DotDetectionResult detect_all(size_t count,
                              const std::function<cv::Mat(size_t, std::string&)>& load,
                              const DotGridSpec& board, const DotCentroidOptions& options,
                              int camera) {
  check_spec(board);
  DotDetectionResult out;
  ImageSetCheck images;
  for (size_t frame = 0; frame < count; ++frame) {
    std::string name;
    const cv::Mat gray = load(frame, name);
    if (std::string reason = images.reason(gray); !reason.empty()) {
      out.rejected.push_back({name, std::move(reason)});
      continue;
    }
    const GrayImageView view{name, gray.data, gray.cols, gray.rows, static_cast<int>(gray.step)};
    detect_one(view, static_cast<int>(frame), board, options, camera, out);
  }
  if (!images.size().empty())
    out.set.image_sizes[camera] = {images.size().width, images.size().height};
  return out;
}

}  // namespace

DotDetectionResult detect_dot_grids(const std::vector<std::string>& image_paths,
                                    const DotGridSpec& board, const DotCentroidOptions& centroid,
                                    int camera) {
  return detect_all(
      image_paths.size(),
      [&](size_t i, std::string& name) {
        name = image_paths[i];
        return cv::imread(name, cv::IMREAD_GRAYSCALE);
      },
      board, centroid, camera);
}

DotDetectionResult detect_dot_grids(const std::vector<GrayImageView>& images,
                                    const DotGridSpec& board, const DotCentroidOptions& centroid,
                                    int camera) {
  return detect_all(
      images.size(),
      [&](size_t i, std::string& name) {
        name = images[i].name;
        if (images[i].pixels == nullptr) return cv::Mat();
        return cv::Mat(images[i].height, images[i].width, CV_8UC1,
                       const_cast<std::uint8_t*>(images[i].pixels),
                       static_cast<size_t>(images[i].stride));
      },
      board, centroid, camera);
}

}  // namespace storetrack::calib
