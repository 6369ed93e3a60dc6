// One camera's observations grouped by board pose (frame): the solvers' working set.
#pragma once

#include <vector>

#include "storetrack/calib/observations.hpp"

namespace storetrack::calib {

struct BoardView {
  int frame = 0;
  std::vector<const Observation*> points;  ///< into the ObservationSet, which outlives this
};

}  // namespace storetrack::calib
