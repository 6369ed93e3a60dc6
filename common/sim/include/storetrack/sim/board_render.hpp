// Calibration-board images with known truth: a planar chessboard seen by a camera of the
// project's model (common/camera, distortion included) at a pose T_c_b, anti-aliased by exact
// area coverage, blurred by the optics PSF and exposed through the sensor model of render.hpp
// (the same Poisson + read noise + quantisation as the spot frames). See common/sim/README.md.
//
// Board frame b (docs/calibration.md, observation CSV): origin at inner corner 0, x along a row
// (cols), y along a column (rows), z = 0 on the board; inner corner id = row * cols + col at
// (col, row) * square_m. Rendering a board once to expected electrons and exposing it many times
// (expose() in render.hpp) gives fresh noise on the same scene cheaply (Monte Carlo).
#pragma once

#include <cstdint>
#include <random>
#include <vector>

#include "storetrack/camera/camera_model.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/sim/render.hpp"

namespace storetrack::sim {

struct ChessboardTarget {
  int cols = 10, rows = 7;  ///< inner corners per row / per column
  double square_m = 0.08;
  /// White border around the squares, in squares (the detector needs a quiet zone).
  int margin_squares = 1;

  /// Inner corner `id` (row * cols + col) in the board frame [m].
  geometry::Vec3 corner(int id) const {
    return {(id % cols) * square_m, (id / cols) * square_m, 0.0};
  }
  int num_corners() const { return cols * rows; }
  /// Centre of the inner-corner grid in the board frame [m].
  geometry::Vec3 centre() const {
    return {(cols - 1) * square_m / 2, (rows - 1) * square_m / 2, 0};
  }
  /// The board's four outer corners (white border included) in the board frame [m].
  std::vector<geometry::Vec3> outline() const;
};

/// Reflected light of the board (signal electrons per pixel over the exposure, added to the
/// sensor's background_e) and the optics blur.
struct BoardPhotometry {
  double white_e = 3600;      ///< white squares and border
  double black_e = 300;       ///< black squares
  double surround_e = 900;    ///< everything that is not the board
  double psf_sigma_px = 0.8;  ///< Gaussian PSF of the optics (the spot renderer's psf_sigma_px)
  SensorModel sensor;
};

/// Expected electrons per pixel (background included), row-major, width x height of the camera.
struct BoardExpectedImage {
  int width = 0, height = 0;
  std::vector<float> electrons;
};

/// Renders the noise-free expected image. Pixel values are the exact area coverage of each
/// pixel by the board's squares, border and surround (pixels cut by one edge: closed form; by
/// two or more, i.e. at corners: 16 x 16 samples), with the pixel -> board map interpolated
/// bilinearly from exact unprojections on a 4-px grid (its error is < 0.002 px across the
/// simulator's lenses), then the Gaussian PSF (separable, sampled, normalised).
/// A board seen from its back (sees_board_back) is plain white: its back is opaque.
void render_board_expected(const camera::CameraModel& camera, const geometry::Transform& T_c_b,
                           const ChessboardTarget& board, const BoardPhotometry& photometry,
                           BoardExpectedImage& out);

/// True projections of every inner corner (nullopt behind the camera), index = corner id.
std::vector<std::optional<geometry::Vec2>> project_board_corners(const camera::CameraModel& camera,
                                                                 const geometry::Transform& T_c_b,
                                                                 const ChessboardTarget& board);

/// True when the camera sees the board's back (the pattern faces -z_b, away from the board's
/// normal z_b). The back is opaque and plain: render_board_expected draws it white.
bool sees_board_back(const geometry::Transform& T_c_b);

/// Angle between the board's normal and the line of sight to its centre [deg] (0 = facing the
/// camera; > 90 = its back).
double board_incidence_deg(const geometry::Transform& T_c_b, const ChessboardTarget& board);

/// The whole board (border included) lies in front of the camera and at least `margin_px`
/// inside the image, its squares at least `min_square_px` wide there, the camera sees its
/// patterned face (not its back: a real operator cannot show a camera the pattern from behind)
/// and at most `max_incidence_deg` from its normal (at its centre).
bool board_fully_visible(const camera::CameraModel& camera, const geometry::Transform& T_c_b,
                         const ChessboardTarget& board, double margin_px = 10,
                         double min_square_px = 12, double max_incidence_deg = 65);

}  // namespace storetrack::sim
