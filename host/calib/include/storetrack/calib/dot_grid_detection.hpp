// Dot-grid observations from images, measured with the camera unit's own centroider
// (estimation/centroid), so calibration marks and flight marks share one centroid model and its
// sigma (docs/calibration.md, "Dot grids"). Two boards:
//  - kDots: a symmetric cols x rows grid of dots, the whole grid in view, indexed by OpenCV's
//    findCirclesGrid run on the centroider's dots (OpenCV's order and 180-degree convention);
//  - kRingDots: a grid that may be larger than the field of view, indexed from three ring
//    (donut) marker dots: the origin, an x marker and a y marker (DICe's
//    BLACK_ON_WHITE_W_DONUT_DOTS target), then grown node by node through a homography.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "storetrack/calib/chessboard_detection.hpp"
#include "storetrack/calib/observations.hpp"

namespace storetrack::calib {

enum class DotBoardKind { kDots, kRingDots };

struct DotGridSpec {
  DotBoardKind kind = DotBoardKind::kRingDots;
  int cols = 10, rows = 8;  ///< dots per row / per column of the grid model
  double spacing_m = 0.0035;
  bool dark_dots = true;  ///< black dots on white (the image is inverted for the centroider)
  // Ring-dot markers (kRingDots only), as DICe's target description: the origin dot is at grid
  // (origin_col, origin_row); the x marker is the origin_to_x_marker-th dot from the origin
  // along +x counting the origin as the first (so origin_to_x_marker - 1 spacings away), the y
  // marker likewise along +y. Seen from the printed side the y marker is 90 degrees
  // counter-clockwise from the x marker (mathematical axes on the print).
  int origin_col = 2, origin_row = 2;
  int origin_to_x_marker = 6, origin_to_y_marker = 4;
};

/// The centroider's noise model for sigma_px (docs/centroiding.md): the camera's EMVA 1288
/// data for the images' format. Dots are measured with CentroidConfig's defaults otherwise;
/// the background tiles and refinement patch are sized from the dots (see the .cpp).
struct DotCentroidOptions {
  double gain_e_per_dn = 20.0;
  double read_noise_e = 12.0;
  double threshold_sigma = 6.0;
};

/// An 8-bit grayscale image in memory (rows of `stride` bytes); `name` names it in reasons.
struct GrayImageView {
  std::string name;
  const std::uint8_t* pixels = nullptr;
  int width = 0, height = 0, stride = 0;
};

/// A dot the centroider measured that is not in the observations, and why.
struct RejectedDot {
  std::string image;
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();
  std::string reason;
};

struct DotDetectionResult {
  ObservationSet set;  ///< sigma_px = the centroider's per-dot sigma
  int images_used = 0;
  std::vector<RejectedImage> rejected;  ///< every image not used, with why
  std::vector<RejectedDot> rejected_dots;
  /// Per used frame: the marker dots' pixels (origin, x marker, y marker; kRingDots only).
  std::vector<std::pair<int, std::array<Eigen::Vector2d, 3>>> markers;
};

/// Frame index = position of the image in the list (a rejected image keeps its index).
DotDetectionResult detect_dot_grids(const std::vector<std::string>& image_paths,
                                    const DotGridSpec& board, const DotCentroidOptions& centroid,
                                    int camera);
DotDetectionResult detect_dot_grids(const std::vector<GrayImageView>& images,
                                    const DotGridSpec& board, const DotCentroidOptions& centroid,
                                    int camera);

}  // namespace storetrack::calib
