// Chessboard corners from images (OpenCV findChessboardCorners, findChessboardCornersSB as the
// quick search where it fails, cornerSubPix). OpenCV stays in the implementation: this header
// only names files and observations.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "storetrack/calib/observations.hpp"

namespace storetrack::calib {

struct ChessboardSpec {
  int cols = 9, rows = 6;  ///< inner corners per row / per column
  double square_m = 0.025;
};

struct RejectedImage {
  std::string path;
  std::string reason;
};

struct DetectionResult {
  ObservationSet set;
  int images_used = 0;
  std::vector<RejectedImage> rejected;  ///< every image not used, with why
};

/// Frame index = position of the image in `image_paths` (so a rejected image keeps its index
/// and the frames of two cameras' image lists stay aligned).
DetectionResult detect_chessboards(const std::vector<std::string>& image_paths,
                                   const ChessboardSpec& board, int camera);

/// One 8-bit grey image in memory (row-major, `stride` bytes per row), the same detector and
/// sub-pixel settings as detect_chessboards: appends its corners as `frame` of `camera` to
/// `set` and returns true, or returns false, appends nothing and puts why in `*reason` (when
/// given): board not found, not wholly in view, or too oblique.
bool detect_chessboard_image(const std::uint8_t* gray, int width, int height, int stride,
                             const ChessboardSpec& board, int camera, int frame,
                             ObservationSet& set, std::string* reason = nullptr);

}  // namespace storetrack::calib
