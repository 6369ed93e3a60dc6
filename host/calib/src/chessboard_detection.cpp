// Chessboard detection with OpenCV's detector and sub-pixel refinement, settings as OpenCV's
// samples/cpp/calibration.cpp (so its published calibrations of the same images reproduce).
#include <algorithm>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "storetrack/calib/chessboard_detection.hpp"

namespace storetrack::calib {
namespace {

std::string size_text(const cv::Size& s) {
  return std::to_string(s.width) + "x" + std::to_string(s.height);
}

bool detect_in(const cv::Mat& gray, const ChessboardSpec& board, int camera, int frame,
               ObservationSet& set) {
  const cv::Size pattern(board.cols, board.rows);
  std::vector<cv::Point2f> corners;
  const int flags = cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE;
  // findChessboardCorners' quad search grows much faster than the pixel count: on rendered
  // 1920 x 1024 frames it took ~30 s per image. Large images are searched at an integer
  // reduction (area average) to at most kSearchSidePx, the corners mapped back (pixel centre i
  // of the reduced image is at s i + (s - 1) / 2) and refined by cornerSubPix at full
  // resolution. Images up to kSearchSidePx (the OpenCV set) take the unchanged path.
  constexpr int kSearchSidePx = 1024;
  const int reduction = (std::max(gray.cols, gray.rows) + kSearchSidePx - 1) / kSearchSidePx;
  if (reduction <= 1) {
    if (!cv::findChessboardCorners(gray, pattern, corners, flags)) return false;
  } else {
    cv::Mat small;
    cv::resize(gray, small, cv::Size(gray.cols / reduction, gray.rows / reduction), 0, 0,
               cv::INTER_AREA);
    if (!cv::findChessboardCorners(small, pattern, corners, flags)) return false;
    const float s = static_cast<float>(reduction), offset = (s - 1) / 2;
    for (cv::Point2f& p : corners)
      p = cv::Point2f(s * p.x + offset, s * p.y + offset);
  }
  cv::cornerSubPix(gray, corners, cv::Size(11, 11), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 30, 1e-4));
  for (int i = 0; i < static_cast<int>(corners.size()); ++i) {
    Observation o;
    o.camera = camera;
    o.frame = frame;
    o.point_id = i;  // OpenCV orders corners row by row: i = row * cols + col
    o.p_board = {(i % board.cols) * board.square_m, (i / board.cols) * board.square_m, 0.0};
    o.pixel = {corners[static_cast<size_t>(i)].x, corners[static_cast<size_t>(i)].y};
    set.observations.push_back(o);
  }
  return true;
}

}  // namespace

bool detect_chessboard_image(const std::uint8_t* gray, int width, int height, int stride,
                             const ChessboardSpec& board, int camera, int frame,
                             ObservationSet& set) {
  // cv::Mat over the caller's pixels (no copy); OpenCV only reads them.
  const cv::Mat image(height, width, CV_8UC1, const_cast<std::uint8_t*>(gray),
                      static_cast<std::size_t>(stride));
  if (!detect_in(image, board, camera, frame, set)) return false;
  set.image_sizes[camera] = {width, height};
  return true;
}

DetectionResult detect_chessboards(const std::vector<std::string>& image_paths,
                                   const ChessboardSpec& board, int camera) {
  DetectionResult out;
  cv::Size image_size;
  for (size_t frame = 0; frame < image_paths.size(); ++frame) {
    const std::string& path = image_paths[frame];
    const cv::Mat gray = cv::imread(path, cv::IMREAD_GRAYSCALE);
    if (gray.empty()) {
      out.rejected.push_back({path, "unreadable (missing file or not an image OpenCV decodes)"});
      continue;
    }
    if (image_size.empty()) image_size = gray.size();
    if (gray.size() != image_size) {
      out.rejected.push_back({path, "image size " + size_text(gray.size()) +
                                        " differs from the first image's " +
                                        size_text(image_size)});
      continue;
    }
    if (!detect_in(gray, board, camera, static_cast<int>(frame), out.set)) {
      out.rejected.push_back({path, "board not found (" + std::to_string(board.cols) + "x" +
                                        std::to_string(board.rows) + " inner corners)"});
      continue;
    }
    out.set.frame_sources[static_cast<int>(frame)] = path;
    ++out.images_used;
  }
  if (!image_size.empty()) out.set.image_sizes[camera] = {image_size.width, image_size.height};
  return out;
}

}  // namespace storetrack::calib
