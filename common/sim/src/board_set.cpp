// Board set planning: see board_set.hpp. Poses are drawn by rejection: a candidate is kept when
// the cameras it is planned for see the whole board within the set's limits.
#include "storetrack/sim/board_set.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <random>
#include <stdexcept>

#include <nlohmann/json.hpp>

namespace storetrack::sim {
namespace {

using geometry::Mat3;
using geometry::Transform;
using geometry::Vec2;
using geometry::Vec3;

constexpr int kMaxTries = 20000;
constexpr double kDeg = M_PI / 180;

std::uint64_t mix(std::uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

// A unit vector perpendicular to n, at a uniform random angle.
Vec3 random_perpendicular(const Vec3& n, std::mt19937_64& rng) {
  const Vec3 a = n.unitOrthogonal();
  const Vec3 b = n.cross(a);
  const double phi = std::uniform_real_distribution<double>(0, 2 * M_PI)(rng);
  return std::cos(phi) * a + std::sin(phi) * b;
}

// Board pose in the world: centre of the corner grid at p_w, board normal (board z, pointing
// away from the cameras) `z_w`, board x along `x_hint_w` projected into the board plane and
// turned by `in_plane_rad` about z.
Transform board_pose(const ChessboardTarget& board, const Vec3& p_w, const Vec3& z_w,
                     const Vec3& x_hint_w, double in_plane_rad) {
  const Vec3 z = z_w.normalized();
  Vec3 x = (x_hint_w - x_hint_w.dot(z) * z);
  x = x.norm() > 1e-9 ? x.normalized() : z.unitOrthogonal();
  x = Eigen::AngleAxisd(in_plane_rad, z) * x;
  Mat3 R;
  R.col(0) = x;
  R.col(1) = z.cross(x);
  R.col(2) = z;
  Transform T = Transform::Identity();
  T.linear() = R;
  T.translation() = p_w - R * board.centre();
  return T;
}

Vec3 tilt(const Vec3& z, double angle_rad, std::mt19937_64& rng) {
  return Eigen::AngleAxisd(angle_rad, random_perpendicular(z, rng)) * z;
}

bool sees(const camera::CalibratedCamera& cam, const Transform& T_w_b, const BoardSetOptions& o) {
  return board_fully_visible(cam.model, cam.T_c_w * T_w_b, o.board, o.margin_px, o.min_square_px,
                             o.max_incidence_deg);
}

Vec3 camera_centre_w(const camera::CalibratedCamera& cam) {
  return cam.T_c_w.inverse().translation();
}

Transform plan_common(const camera::CalibratedCamera& ref, const camera::CalibratedCamera& other,
                      const BoardSetOptions& o, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> unit(0, 1);
  const camera::Intrinsics& in = ref.model.intrinsics();
  const Transform T_w_ref = ref.T_c_w.inverse();
  for (int t = 0; t < kMaxTries; ++t) {
    const Vec2 pixel(in.width * (0.1 + 0.8 * unit(rng)), in.height * (0.1 + 0.8 * unit(rng)));
    const auto xy = ref.model.unproject(pixel);
    if (!xy) continue;
    const double depth = o.min_depth_m + (o.max_depth_m - o.min_depth_m) * unit(rng);
    const Vec3 p_w = T_w_ref * Vec3(xy->x() * depth, xy->y() * depth, depth);
    const Vec3 to_ref = (camera_centre_w(ref) - p_w).normalized();
    const Vec3 to_other = (camera_centre_w(other) - p_w).normalized();
    const Vec3 z_w = tilt(-(to_ref + to_other).normalized(), (5 + 25 * unit(rng)) * kDeg, rng);
    const Transform T_w_b =
        board_pose(o.board, p_w, z_w, T_w_ref.linear().col(0), (-25 + 50 * unit(rng)) * kDeg);
    if (sees(ref, T_w_b, o) && sees(other, T_w_b, o)) return T_w_b;
  }
  throw std::runtime_error(
      "board set: no board pose that camera " + std::to_string(ref.camera_id) + " and camera " +
      std::to_string(other.camera_id) + " both see whole (depth " + std::to_string(o.min_depth_m) +
      "-" + std::to_string(o.max_depth_m) + " m in camera " + std::to_string(ref.camera_id) + ")");
}

Transform plan_single(const camera::CalibratedCamera& cam, int cell, const BoardSetOptions& o,
                      std::mt19937_64& rng) {
  std::uniform_real_distribution<double> unit(0, 1);
  const camera::Intrinsics& in = cam.model.intrinsics();
  const Transform T_w_c = cam.T_c_w.inverse();
  const std::vector<Vec3> outline = o.board.outline();
  const double extent_m = (outline[2] - outline[0]).head<2>().maxCoeff();
  double fill = o.single_view_fill;
  for (int t = 0; t < kMaxTries; ++t) {
    if (t > 0 && t % 500 == 0) fill *= 0.9;  // the grid's corners may need a smaller board
    const double fx = 0.2 + 0.3 * (cell % 3) + 0.08 * (unit(rng) - 0.5);
    const double fy = 0.2 + 0.3 * (cell / 3) + 0.08 * (unit(rng) - 0.5);
    const auto xy = cam.model.unproject(Vec2(in.width * fx, in.height * fy));
    if (!xy) continue;
    const double depth = in.fx * extent_m / (fill * in.width * (0.85 + 0.3 * unit(rng)));
    const Vec3 p_c(xy->x() * depth, xy->y() * depth, depth);
    const Vec3 z_c = tilt(p_c.normalized(), (20 + 20 * unit(rng)) * kDeg, rng);
    const Transform T_c_b =
        board_pose(o.board, p_c, z_c, Vec3::UnitX(), (-20 + 40 * unit(rng)) * kDeg);
    const Transform T_w_b = T_w_c * T_c_b;
    if (sees(cam, T_w_b, o)) return T_w_b;
  }
  throw std::runtime_error("board set: no board pose camera " + std::to_string(cam.camera_id) +
                           " sees whole in image cell " + std::to_string(cell));
}

nlohmann::json pose_json(const Transform& T) {
  const Vec3 rv = geometry::rotvec_from_rotation(T.linear());
  const Vec3 t = T.translation();
  return {{"rotation_vector_rad", {rv.x(), rv.y(), rv.z()}},
          {"translation_m", {t.x(), t.y(), t.z()}}};
}

}  // namespace

std::uint64_t board_image_seed(std::uint64_t seed, int frame, int camera_id) {
  return mix(seed ^ mix(0xB0A4Dull * 0x100000001B3ull ^
                        mix(static_cast<std::uint64_t>(frame) * 0x9E3779B1ull +
                            static_cast<std::uint64_t>(camera_id))));
}

std::vector<BoardFrame> plan_board_frames(const camera::RigCalibration& rig,
                                          const BoardSetOptions& options, std::uint64_t seed) {
  if (rig.cameras.empty()) throw std::runtime_error("board set: the rig has no cameras");
  std::mt19937_64 rng(mix(seed ^ 0xCA11B4A7Eull));
  std::vector<BoardFrame> frames;
  const auto add = [&](const Transform& T_w_b, const char* kind, int camera_id) {
    BoardFrame f;
    f.frame = static_cast<int>(frames.size());
    f.T_w_b = T_w_b;
    f.kind = kind;
    f.planned_camera = camera_id;
    for (const camera::CalibratedCamera& cam : rig.cameras) {
      if (sees(cam, T_w_b, options)) f.cameras_seeing.push_back(cam.camera_id);
    }
    frames.push_back(std::move(f));
  };
  const camera::CalibratedCamera& ref = rig.cameras.front();
  for (std::size_t c = 1; c < rig.cameras.size(); ++c) {
    for (int k = 0; k < options.common_views; ++k)
      add(plan_common(ref, rig.cameras[c], options, rng), "common", rig.cameras[c].camera_id);
  }
  for (const camera::CalibratedCamera& cam : rig.cameras) {
    for (int k = 0; k < options.single_views; ++k)
      add(plan_single(cam, k % 9, options, rng), "single", cam.camera_id);
  }
  return frames;
}

void write_board_truth_json(const camera::RigCalibration& rig, const BoardSetOptions& options,
                            const std::vector<BoardFrame>& frames, std::uint64_t seed,
                            const std::string& image_pattern, const std::string& path) {
  using nlohmann::json;
  const ChessboardTarget& b = options.board;
  json doc = {{"format", "storetrack-board-truth"},
              {"version", 1},
              {"seed", seed},
              {"board",
               {{"type", "chessboard"},
                {"cols", b.cols},
                {"rows", b.rows},
                {"square_m", b.square_m},
                {"margin_squares", b.margin_squares}}},
              {"rig_true", "rig_true.json"},
              {"images", image_pattern}};
  json jf = json::array();
  for (const BoardFrame& f : frames) {
    json cams = json::array();
    for (const camera::CalibratedCamera& cam : rig.cameras) {
      const Transform T_c_b = board_in_camera(cam, f);
      const bool whole = std::find(f.cameras_seeing.begin(), f.cameras_seeing.end(),
                                   cam.camera_id) != f.cameras_seeing.end();
      json corners = json::array();
      for (const auto& p : project_board_corners(cam.model, T_c_b, b)) {
        if (p) {
          corners.push_back({p->x(), p->y()});
        } else {
          corners.push_back(nullptr);
        }
      }
      cams.push_back({{"camera_id", cam.camera_id},
                      {"board_whole_in_view", whole},
                      {"T_c_b", pose_json(T_c_b)},
                      {"incidence_deg", board_incidence_deg(T_c_b, b)},
                      {"corners_px", corners}});
    }
    jf.push_back({{"frame", f.frame},
                  {"kind", f.kind},
                  {"planned_camera", f.planned_camera},
                  {"T_w_b", pose_json(f.T_w_b)},
                  {"cameras", cams}});
  }
  doc["frames"] = jf;
  std::ofstream out(path);
  out << doc.dump(1) << "\n";
  if (!out) throw std::runtime_error(path + ": cannot write the board truth file");
}

}  // namespace storetrack::sim
