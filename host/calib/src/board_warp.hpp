// The board's out-of-plane deflection: mrcal's "calobject_warp"
// (http://mrcal.secretsauce.net/formulation.html, "Calibration object"), a paraboloid over the
// board z_warp = c_x (1 - xn^2) + c_y (1 - yn^2), with xn, yn the board coordinates scaled to
// [-1, 1] over the board's extent: zero at the edges, c_x + c_y at the centre. Two parameters
// per physical board, shared by all its views (docs/calibration.md, "Board deflection").
#pragma once

#include <algorithm>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "board_views.hpp"
#include "storetrack/calib/intrinsic_calibration.hpp"

namespace storetrack::calib {

struct BoardWarp {
  double x_mid = 0, x_half = 1, y_mid = 0, y_half = 1;  ///< extent of the board points [m]
  Eigen::Vector2d c = Eigen::Vector2d::Zero();          ///< (c_x, c_y) [m]
  bool fitted = false;                                  ///< false: c stays 0, no parameters

  /// The extent of every board point of `views`.
  static BoardWarp over(const std::vector<BoardView>& views) {
    Eigen::Vector2d lo = Eigen::Vector2d::Constant(INFINITY), hi = -lo;
    for (const BoardView& v : views)
      for (const Observation* o : v.points) {
        lo = lo.cwiseMin(o->p_board.head<2>());
        hi = hi.cwiseMax(o->p_board.head<2>());
      }
    BoardWarp w;
    w.x_mid = 0.5 * (lo.x() + hi.x());
    w.y_mid = 0.5 * (lo.y() + hi.y());
    w.x_half = std::max(0.5 * (hi.x() - lo.x()), 1e-12);
    w.y_half = std::max(0.5 * (hi.y() - lo.y()), 1e-12);
    return w;
  }

  /// d z_warp / d (c_x, c_y) at board point p.
  Eigen::Vector2d basis(const Eigen::Vector3d& p) const {
    const double xn = (p.x() - x_mid) / x_half, yn = (p.y() - y_mid) / y_half;
    return {1 - xn * xn, 1 - yn * yn};
  }

  /// The board point with the deflection `coefficients` added to its (surveyed) z.
  Eigen::Vector3d apply(const Eigen::Vector3d& p, const double* coefficients) const {
    return p +
           Eigen::Vector3d(0, 0, basis(p).dot(Eigen::Vector2d(coefficients[0], coefficients[1])));
  }
  Eigen::Vector3d apply(const Eigen::Vector3d& p) const { return apply(p, c.data()); }
};

/// The result's statement of a fit's deflection.
inline BoardDeflectionResult deflection_result(const BoardWarp& w,
                                               const Eigen::Matrix2d& covariance,
                                               std::string reason) {
  return {w.fitted,           std::move(reason),  w.c,
          covariance,         w.x_mid - w.x_half, w.x_mid + w.x_half,
          w.y_mid - w.y_half, w.y_mid + w.y_half};
}

/// Applies options.board_deflection to `warp` (its extent set over `views`, its c left as is);
/// returns the reason stated in the result. Auto fits when the identifiability rule holds:
/// >= 3 distinct board x and >= 3 distinct y (a parabola per axis), >= 3 views. Throws
/// CalibrationError ("<who>the board deflection cannot be fitted: ...") when `on` is asked of
/// views that cannot determine it. In intrinsic_calibration.cpp.
std::string decide_deflection(const std::vector<BoardView>& views, const IntrinsicOptions& options,
                              BoardWarp& warp, const std::string& who);

}  // namespace storetrack::calib
