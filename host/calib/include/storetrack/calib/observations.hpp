// Board observations: which board point each camera saw where (docs/calibration.md, "Observation
// CSV"). Written by `storetrack-calib detect`, read by the solvers; also the import format for
// corners detected by other tools (mrcal, caliscope, OpenCV scripts).
#pragma once

#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace storetrack::calib {

/// Thrown on malformed observation files; what() is "<file>:<line>: <field>: <reason>".
class ObservationFileError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// One board point seen by one camera in one frame (one board pose).
struct Observation {
  int camera = 0;
  int frame = 0;     ///< board pose index; shared by all cameras triggered together
  int point_id = 0;  ///< board point index (chessboard: row * cols + col)
  Eigen::Vector3d p_board = Eigen::Vector3d::Zero();  ///< board point in the board frame [m]
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();    ///< image point [px], conventions.md
  std::optional<double> sigma_px;                     ///< per-axis standard uncertainty [px]

  /// The sigma the fit weighs the point with: the stated one, else 1 px (then the residual
  /// variance, estimated from the fit, scales the covariance).
  double weighting_sigma_px() const { return sigma_px.value_or(1.0); }
};

struct ImageSize {
  int width = 0, height = 0;
};

struct ObservationSet {
  std::vector<Observation> observations;
  std::map<int, ImageSize> image_sizes;      ///< per camera, from "# image_size" lines
  std::map<int, std::string> frame_sources;  ///< frame -> image file, from "# frame" lines
};

/// One board per observation set: a point id keeps one board position (within
/// kBoardPositionTolerance_m) in every frame, camera and file. "" when `here` agrees with
/// `before` (the position seen first, `where_before`: "line 12", "in a.csv"), else the reason,
/// "<column>: point <id> at (x, y, z) m, but (x', y', z') m <where_before> ..." naming the
/// first coordinate that differs and the scale between the two (a different square size?).
inline constexpr double kBoardPositionTolerance_m = 1e-6;
std::string board_position_conflict(int point_id, const Eigen::Vector3d& here,
                                    const Eigen::Vector3d& before, const std::string& where_before);

/// Throws ObservationFileError "<file>:<line>: <field>: <reason>" on malformed input, a
/// duplicate (camera, frame, point) or a point whose board position differs from its first.
ObservationSet read_observations_csv(const std::string& path);
ObservationSet parse_observations_csv(const std::string& text, const std::string& origin);
void write_observations_csv(const ObservationSet& set, const std::string& path);
std::string format_observations_csv(const ObservationSet& set);

}  // namespace storetrack::calib
