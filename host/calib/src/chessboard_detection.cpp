// Chessboard detection with OpenCV's detector and sub-pixel refinement, settings as OpenCV's
// samples/cpp/calibration.cpp (so its published calibrations of the same images reproduce).
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "storetrack/calib/chessboard_detection.hpp"

namespace storetrack::calib {
namespace {

std::string size_text(const cv::Size& s) {
  return std::to_string(s.width) + "x" + std::to_string(s.height);
}

}  // namespace

DetectionResult detect_chessboards(const std::vector<std::string>& image_paths,
                                   const ChessboardSpec& board, int camera) {
  DetectionResult out;
  const cv::Size pattern(board.cols, board.rows);
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
    std::vector<cv::Point2f> corners;
    const int flags = cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE;
    if (!cv::findChessboardCorners(gray, pattern, corners, flags)) {
      out.rejected.push_back({path, "board not found (" + std::to_string(board.cols) + "x" +
                                        std::to_string(board.rows) + " inner corners)"});
      continue;
    }
    cv::cornerSubPix(gray, corners, cv::Size(11, 11), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 30, 1e-4));
    for (int i = 0; i < static_cast<int>(corners.size()); ++i) {
      Observation o;
      o.camera = camera;
      o.frame = static_cast<int>(frame);
      o.point_id = i;  // OpenCV orders corners row by row: i = row * cols + col
      o.p_board = {(i % board.cols) * board.square_m, (i / board.cols) * board.square_m, 0.0};
      o.pixel = {corners[static_cast<size_t>(i)].x, corners[static_cast<size_t>(i)].y};
      out.set.observations.push_back(o);
    }
    out.set.frame_sources[static_cast<int>(frame)] = path;
    ++out.images_used;
  }
  if (!image_size.empty()) out.set.image_sizes[camera] = {image_size.width, image_size.height};
  return out;
}

}  // namespace storetrack::calib
