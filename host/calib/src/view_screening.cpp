// degenerate_view_reason: the checks a view must pass before it enters the calibration.
#include "view_screening.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Dense>

#include "storetrack/calib/observations.hpp"
#include "zhang_initialisation.hpp"

namespace storetrack::calib {
namespace {

// Pixels closer than this (RMS) to one line leave the homography across the line to the noise.
constexpr double kMinPixelSpreadPx = 1.0;

std::string metres(double v) {
  char text[32];
  std::snprintf(text, sizeof text, "%.4g m", v);
  return text;
}

/// Points further than the board tolerance from the line through a and b (nullopt: a == b).
std::optional<int> off_line(const std::vector<Eigen::Vector2d>& p, const Eigen::Vector2d& a,
                            const Eigen::Vector2d& b) {
  const Eigen::Vector2d d = b - a;
  if (d.norm() < kBoardPositionTolerance_m) return std::nullopt;
  const Eigen::Vector2d n = Eigen::Vector2d(-d.y(), d.x()).normalized();
  int off = 0;
  for (const auto& q : p)
    off += std::abs(n.dot(q - a)) > kBoardPositionTolerance_m ? 1 : 0;
  return off;
}

/// Names the line of a (nearly) collinear board view: a row, a column or another line.
std::string board_line(const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  const Eigen::Vector2d d = b - a;
  if (std::abs(d.y()) < kBoardPositionTolerance_m)
    return "one board row (y = " + metres(a.y()) + ")";
  if (std::abs(d.x()) < kBoardPositionTolerance_m)
    return "one board column (x = " + metres(a.x()) + ")";
  return "one line of the board";
}

/// The collinear-board reason, or "". Of the first three points two lie on the line holding all
/// but one point, so the three lines through pairs of them are the only candidates.
std::string collinear_board(const std::vector<Eigen::Vector2d>& p) {
  const int n = static_cast<int>(p.size());
  for (const auto& [i, j] : {std::pair{0, 1}, std::pair{0, 2}, std::pair{1, 2}}) {
    const auto off = off_line(p, p[static_cast<size_t>(i)], p[static_cast<size_t>(j)]);
    if (!off || *off > 1) continue;
    const std::string line = board_line(p[static_cast<size_t>(i)], p[static_cast<size_t>(j)]);
    if (*off == 0)
      return "all " + std::to_string(n) + " points on " + line +
             ": no homography from collinear points";
    return std::to_string(n - 1) + " of its " + std::to_string(n) + " points on " + line +
           " and one off it: a homography needs 4 points, no 3 of them on one line";
  }
  return "";
}

/// RMS distance of the pixels from their best-fitting line.
double pixel_line_spread(const std::vector<Eigen::Vector2d>& x) {
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& q : x)
    mean += q;
  mean /= static_cast<double>(x.size());
  Eigen::Matrix2d S = Eigen::Matrix2d::Zero();
  for (const auto& q : x)
    S += (q - mean) * (q - mean).transpose();
  S /= static_cast<double>(x.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(S);
  return std::sqrt(std::max(eig.eigenvalues()[0], 0.0));
}

/// Why the view's homography cannot be had, or "" (then H is it).
std::string homography_problem(const BoardView& view, Eigen::Matrix3d& H) {
  H = board_homography(view);
  if (!H.allFinite()) return "its homography is not finite";
  // Scale-free singularity test on the determinant (Hadamard's inequality bounds it by the
  // product of the column norms).
  const double bound = H.col(0).norm() * H.col(1).norm() * H.col(2).norm();
  if (!(std::abs(H.determinant()) > 1e-12 * bound)) return "its homography is singular";
  // A physical view keeps every board point on one side of the board's line at infinity.
  int positive = 0;
  for (const Observation* o : view.points)
    positive += H.row(2).dot(o->p_board.head<2>().homogeneous()) > 0 ? 1 : 0;
  if (positive != 0 && positive != static_cast<int>(view.points.size()))
    return "its homography puts the board's horizon among its points (not one planar view)";
  return "";
}

}  // namespace

std::string degenerate_view_reason(const BoardView& view, Eigen::Matrix3d* homography) {
  const int n = static_cast<int>(view.points.size());
  if (n < kMinPointsPerView)
    return std::to_string(n) + (n == 1 ? " point" : " points") +
           ", a homography needs >= " + std::to_string(kMinPointsPerView);
  std::vector<Eigen::Vector2d> board, pixels;
  for (const Observation* o : view.points) {
    if (!o->p_board.allFinite() || !o->pixel.allFinite())
      return "point " + std::to_string(o->point_id) + ": a coordinate is not finite";
    board.push_back(o->p_board.head<2>());
    pixels.push_back(o->pixel);
  }
  if (std::string why = collinear_board(board); !why.empty()) return why;
  if (const double spread = pixel_line_spread(pixels); spread < kMinPixelSpreadPx) {
    char text[48];
    std::snprintf(text, sizeof text, "%.2f", spread);
    return "its " + std::to_string(n) + " pixels lie within " + text +
           " px (RMS) of one line: the board is seen edge-on";
  }
  Eigen::Matrix3d H;
  std::string why = homography_problem(view, H);
  if (why.empty() && homography) *homography = H;
  return why;
}

}  // namespace storetrack::calib
