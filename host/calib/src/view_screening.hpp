// Views that cannot give a board -> image homography are named and set aside before the closed
// form or the solver sees them: from such a view Zhang's start is NaN, and Ceres then stops with
// its own raw message naming neither camera nor view (issue 28).
#pragma once

#include <string>

#include "board_views.hpp"

namespace storetrack::calib {

/// Fewest points of a usable view: a homography has 8 degrees of freedom.
inline constexpr int kMinPointsPerView = 4;

/// "" when `view` can give a homography, else why not: too few points, a non-finite
/// coordinate, all board points but at most one on one line (a homography needs 4 points, no 3
/// of them collinear), the pixels on one line (the board seen edge-on), or a homography that is
/// not finite, singular, or puts the board's line at infinity among the points. With "" and
/// `homography` not null, *homography = the view's board_homography (zhang_initialisation.hpp).
std::string degenerate_view_reason(const BoardView& view, Eigen::Matrix3d* homography = nullptr);

}  // namespace storetrack::calib
