// ChArUco board corners from images (OpenCV contrib aruco: markers, then the chessboard corners
// between them, sub-pixel). A partial board gives the corners it shows, each with its board id, so
// views may cut the board at the image edges (where distortion is largest). OpenCV stays in the
// implementation: this header only names files and observations.
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

#include "storetrack/calib/chessboard_detection.hpp"
#include "storetrack/calib/observations.hpp"

namespace storetrack::calib {

/// Thrown for a board description OpenCV cannot build (unknown dictionary, marker >= square,
/// more markers than the dictionary has); what() names the option.
class CharucoSpecError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

struct CharucoSpec {
  std::string dictionary = "DICT_5X5_100";  ///< OpenCV's predefined dictionary name
  int squares_x = 9, squares_y = 7;         ///< chessboard squares per row / per column
  double square_m = 0.030;                  ///< square side [m]
  double marker_m = 0.022;                  ///< marker side [m] (< square_m)
  /// Fewest corners for a view to be used: 4 give a homography with no redundancy to expose a
  /// wrong corner, so the default asks for a few more.
  int min_corners = 6;
};

/// A corner the detector saw partly and did not use (its image was used).
struct RejectedCorner {
  int frame = 0;
  int point_id = 0;  ///< ChArUco corner id
  std::string reason;
};

struct CharucoDetectionResult {
  DetectionResult detection;  ///< observations (point_id = ChArUco corner id), rejected images
  std::vector<RejectedCorner> rejected_corners;
};

/// The names `--dictionary` accepts (OpenCV's DICT_* names).
std::vector<std::string> charuco_dictionary_names();

/// Board point of ChArUco corner `id`: OpenCV's layout (corner id = row * (squares_x - 1) + col,
/// x right and y down from the board's outer top-left corner, z = 0), in metres.
Eigen::Vector3d charuco_corner_position(const CharucoSpec& board, int id);

/// Frame index = position of the image in `image_paths` (as detect_chessboards). Throws
/// CharucoSpecError for an impossible board description, before reading any image.
CharucoDetectionResult detect_charuco(const std::vector<std::string>& image_paths,
                                      const CharucoSpec& board, int camera);

}  // namespace storetrack::calib
