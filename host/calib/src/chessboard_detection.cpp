// Chessboard detection with OpenCV's detector and sub-pixel refinement, settings as OpenCV's
// samples/cpp/calibration.cpp (so its published calibrations of the same images reproduce),
// searched so that an image without a whole board is refused in ~0.2 s, and view checks on
// the refined corners (board wholly in view, not too oblique), each with its reason.
#include <algorithm>
#include <cmath>
#include <sstream>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "image_set_check.hpp"
#include "storetrack/calib/chessboard_detection.hpp"

namespace storetrack::calib {
namespace {

std::string pattern_text(const ChessboardSpec& board) {
  return std::to_string(board.cols) + "x" + std::to_string(board.rows) + " inner corners";
}

std::string fixed(double v, int decimals) {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(decimals);
  s << v;
  return s.str();
}

// findChessboardCorners' quad search grows much faster than the pixel count: on rendered
// 1920 x 1024 frames it took ~30 s per image. Large images are searched at an integer
// reduction (area average) to at most kSearchSidePx, the corners mapped back (pixel centre i
// of the reduced image is at s i + (s - 1) / 2) and refined by cornerSubPix at full
// resolution. Images up to kSearchSidePx (the OpenCV set) are searched as they are.
constexpr int kSearchSidePx = 1024;

// Views whose squares the image foreshortens below this (median over the squares of the
// short / long side of each square's local affine map; cos 63 deg) are refused: cornerSubPix's
// 23 x 23 px window then spans strongly sheared squares. On rendered views tilted 65 and
// 71 deg from the line of sight it put corners 7.4 and 0.8 px from the truth; every view the
// board set plans (<= 60 deg) measured >= 0.50 (docs/calibration.md, "Fast rejection").
constexpr double kMinForeshortening = 0.45;

// The quick search, where findChessboardCorners without adaptive thresholding failed:
// findChessboardCornersSB without flags, then with CALIB_CB_NORMALIZE_IMAGE (~0.07 s each,
// with or without a board). Each alone missed a whole view the other found (rendered
// static-scenario views; OpenCV's 9x6 set: without flags it missed 4 of the 26 images).
bool quick_search(const cv::Mat& search, const cv::Size& pattern,
                  std::vector<cv::Point2f>& corners) {
  return cv::findChessboardCornersSB(search, pattern, corners, 0) ||
         cv::findChessboardCornersSB(search, pattern, corners, cv::CALIB_CB_NORMALIZE_IMAGE);
}

// The board's corners in the full-resolution image, OpenCV's order (row by row), or the
// reason there are none. findChessboardCorners with adaptive thresholding (OpenCV's sample's
// flags) takes 1 ms to find a board but seconds to fail on a board cut by the image edge: after
// its histogram-threshold attempts it tries 6 adaptive thresholds x 8 dilations. So:
//  1. findChessboardCorners without CALIB_CB_ADAPTIVE_THRESH: the same histogram-threshold
//     attempts first (the same corners when one of them finds the board), then one global
//     threshold; 1 ms to find a board, ~5 ms to fail. It found 444 of 447 rendered whole
//     views and all 26 images of OpenCV's 9x6 set.
//  2. Failing that, the quick search decides. Its corners are findChessboardCorners' in reverse
//     (i -> n - 1 - i) on a board with one even side, whose corner colours fix its
//     orientation: SB starts at the other colour, with the same handedness (every view both
//     found: seed-1 rendered set 97 and 95, OpenCV's set 22 and 26, without / with the flag).
//     On other boards findChessboardCorners with OpenCV's flags, as before, gives the corners.
std::string search_corners(const cv::Mat& gray, const ChessboardSpec& board,
                           std::vector<cv::Point2f>& corners) {
  const cv::Size pattern(board.cols, board.rows);
  const int reduction = (std::max(gray.cols, gray.rows) + kSearchSidePx - 1) / kSearchSidePx;
  cv::Mat search = gray;
  if (reduction > 1)
    cv::resize(gray, search, cv::Size(gray.cols / reduction, gray.rows / reduction), 0, 0,
               cv::INTER_AREA);
  if (!cv::findChessboardCorners(search, pattern, corners, cv::CALIB_CB_NORMALIZE_IMAGE)) {
    if (!quick_search(search, pattern, corners))
      return "board not found (" + pattern_text(board) + "; findChessboardCorners and " +
             "findChessboardCornersSB on the " + size_text(search.size()) +
             " image): no board, or not wholly in view, too oblique or too small";
    const bool one_even_side = board.cols % 2 != board.rows % 2;
    if (one_even_side) {
      std::reverse(corners.begin(), corners.end());
    } else if (!cv::findChessboardCorners(
                   search, pattern, corners,
                   cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE)) {
      return "board not found (" + pattern_text(board) +
             "): findChessboardCornersSB found it, findChessboardCorners did not (a board " +
             "with both sides odd or both even needs it for the corner order)";
    }
  }
  const float s = static_cast<float>(reduction), offset = (s - 1) / 2;
  for (cv::Point2f& p : corners)
    p = cv::Point2f(s * p.x + offset, s * p.y + offset);
  return {};
}

// A board is wholly in view when the image holds the squares around its inner corners: the
// point half a square beyond each boundary corner (along the grid, through the homography of
// that corner's own square: a straight-line step overshoots under perspective) lies inside
// the image. Half, not a whole square: a board's outer squares may be cut narrower (OpenCV's
// 9x6 board: its outer row reached 27.6 px beyond the edge of right08.jpg, a whole square out,
// while the board is in view). OpenCV itself finds every inner corner of a board that the
// image edge cuts through its outer squares (rendered views up to 136 px outside). Returns
// the reason, or empty.
std::string outer_squares_outside(const std::vector<cv::Point2f>& c, const ChessboardSpec& board,
                                  const cv::Size& image) {
  double worst = 0;
  int worst_id = -1;
  for (int row = 0; row < board.rows; ++row) {
    for (int col = 0; col < board.cols; ++col) {
      const int out_c = col == 0 ? -1 : (col == board.cols - 1 ? 1 : 0);
      const int out_r = row == 0 ? -1 : (row == board.rows - 1 ? 1 : 0);
      if (out_c == 0 && out_r == 0) continue;  // not on the boundary
      const int c0 = std::min(col, board.cols - 2), r0 = std::min(row, board.rows - 2);
      std::vector<cv::Point2f> grid, pixels;
      for (const auto& [dc, dr] : {std::pair{0, 0}, {1, 0}, {0, 1}, {1, 1}}) {
        grid.emplace_back(static_cast<float>(c0 + dc), static_cast<float>(r0 + dr));
        pixels.push_back(c[static_cast<size_t>((r0 + dr) * board.cols + c0 + dc)]);
      }
      std::vector<cv::Point2f> outer;
      cv::perspectiveTransform(std::vector<cv::Point2f>{{static_cast<float>(col + 0.5 * out_c),
                                                         static_cast<float>(row + 0.5 * out_r)}},
                               outer, cv::getPerspectiveTransform(grid, pixels));
      const cv::Point2f q = outer[0];
      const double outside =
          std::max({-q.x, -q.y, q.x - (image.width - 1), q.y - (image.height - 1)});
      if (outside > worst) {
        worst = outside;
        worst_id = row * board.cols + col;
      }
    }
  }
  if (worst_id < 0) return {};
  return "board not wholly in view (" + pattern_text(board) + "): half a square beyond corner " +
         std::to_string(worst_id) + " lies " + fixed(worst, 1) + " px outside the image";
}

// Median over the board's squares of the short / long singular value of each square's local
// affine map (1 for a board parallel to the image, cos of the tilt for a tilted one).
double median_foreshortening(const std::vector<cv::Point2f>& c, const ChessboardSpec& board) {
  std::vector<double> ratios;
  for (int row = 0; row + 1 < board.rows; ++row) {
    for (int col = 0; col + 1 < board.cols; ++col) {
      const auto at = [&](int dc, int dr) {
        return c[static_cast<size_t>((row + dr) * board.cols + col + dc)];
      };
      const cv::Point2f u = 0.5f * (at(1, 0) - at(0, 0) + at(1, 1) - at(0, 1));
      const cv::Point2f v = 0.5f * (at(0, 1) - at(0, 0) + at(1, 1) - at(1, 0));
      // Singular values of the 2 x 2 matrix [u v]: s1^2 + s2^2 = |u|^2 + |v|^2, s1 s2 = |det|.
      const double sum = u.dot(u) + v.dot(v), det = std::abs(u.cross(v));
      const double root = std::sqrt(std::max(0.0, sum * sum - 4 * det * det));
      const double s1 = std::sqrt((sum + root) / 2), s2 = std::sqrt(std::max(0.0, sum - root) / 2);
      ratios.push_back(s1 > 0 ? s2 / s1 : 0);
    }
  }
  std::nth_element(ratios.begin(), ratios.begin() + static_cast<long>(ratios.size() / 2),
                   ratios.end());
  return ratios[ratios.size() / 2];
}

// Detects the board in one image and appends its corners; returns empty, or the reason the
// image is not used (nothing appended).
std::string detect_in(const cv::Mat& gray, const ChessboardSpec& board, int camera, int frame,
                      ObservationSet& set) {
  std::vector<cv::Point2f> corners;
  std::string reason = search_corners(gray, board, corners);
  if (!reason.empty()) return reason;
  cv::cornerSubPix(gray, corners, cv::Size(11, 11), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 30, 1e-4));
  reason = outer_squares_outside(corners, board, gray.size());
  if (!reason.empty()) return reason;
  const double foreshortening = median_foreshortening(corners, board);
  if (foreshortening < kMinForeshortening)
    return "board too oblique (" + pattern_text(board) + "): its squares are foreshortened to " +
           fixed(foreshortening, 2) + " of their length (median; limit " +
           fixed(kMinForeshortening, 2) + ", a board about 63 deg from the image plane)";
  for (int i = 0; i < static_cast<int>(corners.size()); ++i) {
    Observation o;
    o.camera = camera;
    o.frame = frame;
    o.point_id = i;  // OpenCV orders corners row by row: i = row * cols + col
    o.p_board = {(i % board.cols) * board.square_m, (i / board.cols) * board.square_m, 0.0};
    o.pixel = {corners[static_cast<size_t>(i)].x, corners[static_cast<size_t>(i)].y};
    set.observations.push_back(o);
  }
  return {};
}

}  // namespace

bool detect_chessboard_image(const std::uint8_t* gray, int width, int height, int stride,
                             const ChessboardSpec& board, int camera, int frame,
                             ObservationSet& set, std::string* reason) {
  // cv::Mat over the caller's pixels (no copy); OpenCV only reads them.
  const cv::Mat image(height, width, CV_8UC1, const_cast<std::uint8_t*>(gray),
                      static_cast<std::size_t>(stride));
  std::string why = detect_in(image, board, camera, frame, set);
  if (!why.empty()) {
    if (reason != nullptr) *reason = std::move(why);
    return false;
  }
  set.image_sizes[camera] = {width, height};
  return true;
}

DetectionResult detect_chessboards(const std::vector<std::string>& image_paths,
                                   const ChessboardSpec& board, int camera) {
  DetectionResult out;
  ImageSetCheck images;
  for (size_t frame = 0; frame < image_paths.size(); ++frame) {
    const std::string& path = image_paths[frame];
    const cv::Mat gray = cv::imread(path, cv::IMREAD_GRAYSCALE);
    std::string reason = images.reason(gray);
    if (reason.empty()) reason = detect_in(gray, board, camera, static_cast<int>(frame), out.set);
    if (!reason.empty()) {
      out.rejected.push_back({path, std::move(reason)});
      continue;
    }
    out.set.frame_sources[static_cast<int>(frame)] = path;
    ++out.images_used;
  }
  if (!images.size().empty())
    out.set.image_sizes[camera] = {images.size().width, images.size().height};
  return out;
}

}  // namespace storetrack::calib
