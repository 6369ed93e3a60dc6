// One camera's observations grouped by board pose (frame): the solvers' working set.
#pragma once

#include <optional>
#include <vector>

#include <Eigen/Core>

#include "storetrack/calib/observations.hpp"

namespace storetrack::calib {

struct BoardView {
  int frame = 0;
  std::vector<const Observation*> points;  ///< into the ObservationSet, which outlives this
  /// board -> image of `points`, kept by the screening (view_screening.hpp) for Zhang's start:
  /// the 9 x 9 eigen problem once per view, not twice.
  std::optional<Eigen::Matrix3d> homography;
};

}  // namespace storetrack::calib
