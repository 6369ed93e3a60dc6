// Closed-form start for the intrinsic fit: Z. Zhang, "A flexible new technique for camera
// calibration", IEEE TPAMI 22(11):1330-1334, 2000 (and MSR-TR-98-71, Appendix B).
#pragma once

#include <vector>

#include "board_views.hpp"
#include "storetrack/calib/intrinsic_calibration.hpp"

namespace storetrack::calib {

struct ZhangStart {
  camera::Intrinsics intrinsics;           ///< skew and distortion 0
  std::vector<geometry::Transform> T_c_b;  ///< per view, board -> camera
  const char* method = "";                 ///< which closed form gave the start
};

/// Always gives a start (see the fallbacks in the .cpp); degenerate views are refused later.
ZhangStart zhang_initialisation(const std::vector<BoardView>& views, const ImageSize& size,
                                const IntrinsicOptions& options);

/// Planar homography board (x, y) -> pixel by the normalised DLT (Hartley & Zisserman,
/// "Multiple View Geometry", 2nd ed., alg. 4.2). Needs >= 4 points in general position.
Eigen::Matrix3d board_homography(const BoardView& view);

}  // namespace storetrack::calib
