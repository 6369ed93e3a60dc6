// A calibration board set for a rig with known truth (storetrack-sim --mode boards,
// common/sim/README.md): board poses that camera 0 (the reference) and each other camera see
// together (the rig fit needs common views), plus tilted views spread over each camera's image
// (distortion is only determined where boards were seen), every camera imaging every frame as
// if triggered together (frame number = one board pose, docs/calibration.md step 7).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/sim/board_render.hpp"

namespace storetrack::sim {

struct BoardSetOptions {
  ChessboardTarget board;
  int common_views = 6;  ///< per non-reference camera: frames it and camera 0 both see whole
  int single_views = 9;  ///< per camera: frames on a 3 x 3 grid of its image, tilted 20-40 deg
  double min_depth_m = 0.8, max_depth_m = 3.5;  ///< common views: board centre depth in camera 0
  /// Single views: the board's outline spans about this fraction of the image width.
  double single_view_fill = 0.45;
  double margin_px = 12;      ///< every board point at least this far inside the image
  double min_square_px = 14;  ///< smallest square side in the image
  double max_incidence_deg = 60;
};

struct BoardFrame {
  int frame = 0;
  geometry::Transform T_w_b = geometry::Transform::Identity();  ///< board -> world (rig's w)
  /// "common": planned for camera 0 + `planned_camera` together; "single": for one camera.
  std::string kind;
  int planned_camera = 0;
  /// Cameras (ids) that see the whole board (board_fully_visible with the set's limits).
  std::vector<int> cameras_seeing;
};

/// Plans the frames for the TRUE rig (cameras[0] is the reference). Deterministic in `seed`.
/// Throws std::runtime_error naming the camera when no acceptable pose is found (e.g. camera 0
/// and it share no field of view in the depth range).
std::vector<BoardFrame> plan_board_frames(const camera::RigCalibration& rig,
                                          const BoardSetOptions& options, std::uint64_t seed);

/// T_c_b of a frame for a camera of the rig.
inline geometry::Transform board_in_camera(const camera::CalibratedCamera& camera,
                                           const BoardFrame& frame) {
  return camera.T_c_w * frame.T_w_b;
}

/// Noise seed of one image: a function of (seed, frame, camera id) only.
std::uint64_t board_image_seed(std::uint64_t seed, int frame, int camera_id);

/// The truth file (format "storetrack-board-truth", documented in common/sim/README.md).
void write_board_truth_json(const camera::RigCalibration& rig, const BoardSetOptions& options,
                            const std::vector<BoardFrame>& frames, std::uint64_t seed,
                            const std::string& image_pattern, const std::string& path);

}  // namespace storetrack::sim
