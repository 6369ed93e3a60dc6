// Synthetic board views for the calibration tests and storetrack-calib-bench: SisTrO's board
// (10 x 7 corners, 50 mm) or any other grid, its corners projected by the project's camera model
// with Gaussian pixel noise of known sigma. Header-only on common/camera: no simulator.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <random>

#include <Eigen/Cholesky>
#include <Eigen/Geometry>

#include "storetrack/calib/observations.hpp"
#include "storetrack/camera/camera_model.hpp"
#include "storetrack/geometry/transform.hpp"

namespace storetrack::calib::test {

constexpr int kCols = 10, kRows = 7;
constexpr double kSquare = 0.05;  // [m]

/// The project's nominal sensor (1920 x 1024), values like docs/calibration-file.md.
inline camera::Intrinsics truth_camera() {
  camera::Intrinsics in;
  in.fx = 1450.3;
  in.fy = 1448.7;
  in.cx = 962.1;
  in.cy = 508.4;
  in.dist = {-0.21, 0.09, 0.0004, -0.0003, -0.02, 0, 0, 0};
  return in;
}

struct BoardGrid {
  int cols = kCols, rows = kRows;
  double square_m = kSquare;
  /// The rendered board's true deflection, mrcal's calobject_warp written out here (the
  /// simulator's own copy, not the library's): z = c_x (1 - xn^2) + c_y (1 - yn^2), xn, yn the
  /// corner coordinates scaled to [-1, 1] over the grid.
  double bow_x_m = 0, bow_y_m = 0;
  /// Extra true relief of a non-flat target, z += relief_m sin(pi x / width) cos(pi y / height).
  double relief_m = 0;
  /// The observations carry the true z (a surveyed board); else z = 0 (the nominal flat board).
  bool surveyed = false;
};

/// The true position of corner `id` of the rendered board.
inline geometry::Vec3 true_board_point(const BoardGrid& grid, int id) {
  const double x = (id % grid.cols) * grid.square_m, y = (id / grid.cols) * grid.square_m;
  const double width = (grid.cols - 1) * grid.square_m, height = (grid.rows - 1) * grid.square_m;
  const double xn = 2 * x / width - 1, yn = 2 * y / height - 1;
  const double z = grid.bow_x_m * (1 - xn * xn) + grid.bow_y_m * (1 - yn * yn) +
                   grid.relief_m * std::sin(M_PI * x / width) * std::cos(M_PI * y / height);
  return {x, y, z};
}

/// Appends one view of the board at T_c_b: every corner inside the 1920 x 1024 image, projected
/// from its true position (true_board_point).
inline void add_board_view(const camera::CameraModel& model, const geometry::Transform& T_c_b,
                           int camera, int frame, std::normal_distribution<double>& noise,
                           std::mt19937_64& rng, ObservationSet& set, const BoardGrid& grid = {}) {
  for (int id = 0; id < grid.cols * grid.rows; ++id) {
    Observation o;
    o.camera = camera;
    o.frame = frame;
    o.point_id = id;
    const geometry::Vec3 p_true = true_board_point(grid, id);
    o.p_board = grid.surveyed ? p_true : geometry::Vec3(p_true.x(), p_true.y(), 0);
    const auto pixel = model.project_world(T_c_b, p_true);
    if (!pixel || pixel->x() < 0 || pixel->y() < 0 || pixel->x() > 1919 || pixel->y() > 1023)
      continue;
    o.pixel = *pixel + geometry::Vec2(noise(rng), noise(rng));
    set.observations.push_back(o);
  }
}

/// T_c_b of view i: the board 1.1-1.9 m away, spread over the image, tilted 20-40 degrees about
/// an axis that turns from view to view. parallel = every board with the same orientation.
inline geometry::Transform board_pose(int i, bool parallel, const BoardGrid& grid = {}) {
  const double turn = parallel ? 0.7 : 2.39996 * i;  // golden angle: axes spread evenly
  const double tilt = parallel ? 0.5 : (20 + 20 * ((i * 7) % 11) / 10.0) * M_PI / 180;
  const geometry::Vec3 axis(std::cos(turn), std::sin(turn), 0);
  const geometry::Mat3 R =
      Eigen::AngleAxisd(tilt, axis).toRotationMatrix() *
      Eigen::AngleAxisd(parallel ? 0 : 0.3 * i, geometry::Vec3::UnitZ()).toRotationMatrix();
  const double z = 1.1 + 0.8 * ((i * 5) % 9) / 8.0;
  const geometry::Vec3 centre_cam(0.45 * z * std::cos(1.3 * i), 0.25 * z * std::sin(1.7 * i), z);
  const geometry::Vec3 centre_board(0.5 * (grid.cols - 1) * grid.square_m,
                                    0.5 * (grid.rows - 1) * grid.square_m, 0);
  geometry::Transform T = geometry::Transform::Identity();
  T.linear() = R;
  T.translation() = centre_cam - R * centre_board;
  return T;
}

/// A wide-angle (fisheye) camera on the 1920 x 1024 sensor: Kannala-Brandt with f = 420 px, so
/// that 90 degrees lies ~660 px from the centre: the image spans ~150 degrees vertically and
/// the full 180 horizontally. Coefficients of the size cv::fisheye::calibrate reports for such
/// lenses.
inline camera::Intrinsics fisheye_truth_camera() {
  camera::Intrinsics in;
  in.lens_model = camera::LensModel::kKannalaBrandt;
  in.fx = 421.7;
  in.fy = 420.9;
  in.cx = 963.2;
  in.cy = 509.6;
  in.dist = {-0.013, -0.0067, 0.0037, -0.0012, 0, 0, 0, 0};
  return in;
}

/// T_c_b of wide-angle view i: the board 0.45-0.85 m away, its centre 5-80 degrees off the
/// optical axis (azimuth turning by the golden angle), facing the camera but tilted 20-40
/// degrees about an axis across the line of sight, so that its corners reach the edge of a
/// fisheye's field.
inline geometry::Transform wide_angle_board_pose(int i, const BoardGrid& grid = {}) {
  const double off_axis = (5 + 75 * ((i * 7) % 11) / 10.0) * M_PI / 180;
  const double azimuth = 2.39996 * i;
  const geometry::Vec3 sight(std::sin(off_axis) * std::cos(azimuth),
                             std::sin(off_axis) * std::sin(azimuth), std::cos(off_axis));
  const geometry::Mat3 look =
      Eigen::Quaterniond::FromTwoVectors(geometry::Vec3::UnitZ(), sight).toRotationMatrix();
  const double tilt = (20 + 20 * ((i * 5) % 9) / 8.0) * M_PI / 180;
  const geometry::Vec3 across = look * geometry::Vec3(std::cos(1.7 * i), std::sin(1.7 * i), 0);
  const geometry::Mat3 R = Eigen::AngleAxisd(tilt, across).toRotationMatrix() * look *
                           Eigen::AngleAxisd(0.4 * i, geometry::Vec3::UnitZ()).toRotationMatrix();
  const double distance = 0.45 + 0.4 * ((i * 3) % 7) / 6.0;
  const geometry::Vec3 centre_board(0.5 * (grid.cols - 1) * grid.square_m,
                                    0.5 * (grid.rows - 1) * grid.square_m, 0);
  geometry::Transform T = geometry::Transform::Identity();
  T.linear() = R;
  T.translation() = distance * sight - R * centre_board;
  return T;
}

/// NEES of a fit's free intrinsics against the truth: e^T C^-1 e over the entries `free` of the
/// packed vector (the fixed entries have variance 0 and stay out).
template <std::size_t N>
double free_intrinsics_nees(const camera::Intrinsics& fitted,
                            const camera::IntrinsicCovariance& covariance,
                            const camera::Intrinsics& truth, const std::array<int, N>& free) {
  const camera::IntrinsicVector e = camera::pack(fitted) - camera::pack(truth);
  Eigen::Matrix<double, N, 1> e_free;
  Eigen::Matrix<double, N, N> c_free;
  for (std::size_t a = 0; a < N; ++a) {
    e_free[a] = e[free[a]];
    for (std::size_t b = 0; b < N; ++b)
      c_free(a, b) = covariance(free[a], free[b]);
  }
  return e_free.dot(c_free.ldlt().solve(e_free));
}

}  // namespace storetrack::calib::test
