// Synthetic board views for the calibration tests: SisTrO's board (10 x 7 corners, 50 mm), its
// corners projected by the project's camera model with Gaussian pixel noise of known sigma.
#pragma once

#include <random>

#include "storetrack/calib/observations.hpp"
#include "storetrack/camera/camera_model.hpp"
#include "storetrack/geometry/transform.hpp"

namespace storetrack::calib::test {

constexpr int kCols = 10, kRows = 7;
constexpr double kSquare = 0.05;  // [m]

/// Appends one view of the board at T_c_b: every corner inside the 1920 x 1024 image.
inline void add_board_view(const camera::CameraModel& model, const geometry::Transform& T_c_b,
                           int camera, int frame, std::normal_distribution<double>& noise,
                           std::mt19937_64& rng, ObservationSet& set) {
  for (int id = 0; id < kCols * kRows; ++id) {
    Observation o;
    o.camera = camera;
    o.frame = frame;
    o.point_id = id;
    o.p_board = {(id % kCols) * kSquare, (id / kCols) * kSquare, 0};
    const auto pixel = model.project_world(T_c_b, o.p_board);
    if (!pixel || pixel->x() < 0 || pixel->y() < 0 || pixel->x() > 1919 || pixel->y() > 1023)
      continue;
    o.pixel = *pixel + geometry::Vec2(noise(rng), noise(rng));
    set.observations.push_back(o);
  }
}

}  // namespace storetrack::calib::test
