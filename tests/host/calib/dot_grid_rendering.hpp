// Test helper: dot-grid images with known truth. Each dot (a circle of the board plane) is
// projected through a homography board -> image as a 256-gon, filled 16x supersampled and
// averaged down (area coverage to 1/64 px^2), so the rendered dot is the projected
// ellipse whose centre is known in closed form (the conic H^-T Q H^-1).
#pragma once

#include <cmath>
#include <random>
#include <vector>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

namespace storetrack::calib::test {

struct RenderedDot {
  int col = 0, row = 0;
  bool ring = false;
  Eigen::Vector2d projected_centre;  ///< H * centre
  Eigen::Vector2d ellipse_centre;    ///< centre of the imaged circle (what a centroid measures)
  bool inside = false;               ///< the whole dot lies >= 2 px inside the image
  /// ... and so does the centroider's refinement patch: +-3 s, s from the thresholded second
  /// moment as for a Gaussian cut at the threshold (docs/centroiding.md, fast start); a disc
  /// cut at half its height gives s = (R / 2) / sqrt(1 - ln 2) = 0.9 R, so +-2.7 R, at most
  /// +-64 px (the detector's largest patch). Dots between inside and clear may go either way.
  bool clear = false;
};

/// Centre of the image of the circle (centre c, radius r, board plane) under H.
inline Eigen::Vector2d imaged_circle_centre(const Eigen::Matrix3d& H, const Eigen::Vector2d& c,
                                            double r) {
  Eigen::Matrix3d Q;
  Q << 1, 0, -c.x(), 0, 1, -c.y(), -c.x(), -c.y(), c.squaredNorm() - r * r;
  const Eigen::Matrix3d Hi = H.inverse();
  const Eigen::Matrix3d C = Hi.transpose() * Q * Hi;
  return -C.topLeftCorner<2, 2>().inverse() * C.topRightCorner<2, 1>();
}

/// Coverage (0..1) of the projected disc of radius r at c, over the pixel box [x0, x0 + w) x
/// [y0, y0 + h) (pixel centres at integers, conventions.md).
inline cv::Mat disc_coverage(const Eigen::Matrix3d& H, const Eigen::Vector2d& c, double r, int x0,
                             int y0, int w, int h) {
  constexpr int kSuper = 8, kVertices = 256, kShift = 4;
  std::vector<cv::Point> polygon;
  for (int k = 0; k < kVertices; ++k) {
    const double a = 2 * M_PI * k / kVertices;
    const Eigen::Vector2d p =
        (H * Eigen::Vector3d(c.x() + r * std::cos(a), c.y() + r * std::sin(a), 1)).hnormalized();
    // Supersampled pixel (i, j) covers [x0 - 0.5 + i / S, ...): its centre is at sample i + 0.5.
    const double sx = (p.x() - x0 + 0.5) * kSuper - 0.5, sy = (p.y() - y0 + 0.5) * kSuper - 0.5;
    polygon.emplace_back(static_cast<int>(std::lround(sx * (1 << kShift))),
                         static_cast<int>(std::lround(sy * (1 << kShift))));
  }
  cv::Mat big = cv::Mat::zeros(h * kSuper, w * kSuper, CV_32F);
  cv::fillPoly(big, std::vector<std::vector<cv::Point>>{polygon}, cv::Scalar(1.0), cv::LINE_8,
               kShift);
  cv::Mat small;
  cv::resize(big, small, cv::Size(w, h), 0, 0, cv::INTER_AREA);
  return small;
}

struct DotBoardRender {
  int cols = 14, rows = 10;
  double spacing = 1.0, radius = 0.25, hole_radius = 0.08;  // board units
  std::vector<std::pair<int, int>> rings;                   // (col, row) of ring dots
  double dot_level = 230, ground_level = 30;                // bright-dot image [DN]
  double gain_e_per_dn = 20, read_noise_e = 12;             // noise model; gain <= 0: no noise
  bool dark_dots = false;                                   // store the inverted image
};

/// Renders the board (dot (col, row) at (col, row) * spacing) through H into a w x h image.
inline cv::Mat render_dot_board(const Eigen::Matrix3d& H, const DotBoardRender& b, int w, int h,
                                std::vector<RenderedDot>& truth, std::mt19937_64& rng) {
  cv::Mat coverage = cv::Mat::zeros(h, w, CV_32F);
  truth.clear();
  for (int row = 0; row < b.rows; ++row)
    for (int col = 0; col < b.cols; ++col) {
      RenderedDot d;
      d.col = col, d.row = row;
      for (const auto& [rc, rr] : b.rings)
        d.ring = d.ring || (rc == col && rr == row);
      const Eigen::Vector2d c(col * b.spacing, row * b.spacing);
      d.projected_centre = (H * c.homogeneous()).hnormalized();
      d.ellipse_centre = imaged_circle_centre(H, c, b.radius);
      double xmin = 1e18, xmax = -1e18, ymin = 1e18, ymax = -1e18;
      for (int k = 0; k < 64; ++k) {
        const double a = 2 * M_PI * k / 64;
        const Eigen::Vector2d p =
            (H * Eigen::Vector3d(c.x() + b.radius * std::cos(a), c.y() + b.radius * std::sin(a), 1))
                .hnormalized();
        xmin = std::min(xmin, p.x()), xmax = std::max(xmax, p.x());
        ymin = std::min(ymin, p.y()), ymax = std::max(ymax, p.y());
      }
      d.inside = xmin >= 2 && ymin >= 2 && xmax <= w - 3 && ymax <= h - 3;
      const double half = std::min(64.0, 2.8 * 0.5 * std::max(xmax - xmin, ymax - ymin)) + 2;
      const Eigen::Vector2d m = 0.5 * Eigen::Vector2d(xmin + xmax, ymin + ymax);
      d.clear =
          m.x() - half >= 0 && m.y() - half >= 0 && m.x() + half <= w - 1 && m.y() + half <= h - 1;
      truth.push_back(d);
      const int x0 = std::max(0, static_cast<int>(std::floor(xmin)) - 2);
      const int y0 = std::max(0, static_cast<int>(std::floor(ymin)) - 2);
      const int x1 = std::min(w, static_cast<int>(std::ceil(xmax)) + 3);
      const int y1 = std::min(h, static_cast<int>(std::ceil(ymax)) + 3);
      if (x1 <= x0 || y1 <= y0) continue;
      cv::Mat cov = disc_coverage(H, c, b.radius, x0, y0, x1 - x0, y1 - y0);
      if (d.ring) cov -= disc_coverage(H, c, b.hole_radius, x0, y0, x1 - x0, y1 - y0);
      coverage(cv::Rect(x0, y0, x1 - x0, y1 - y0)) += cov;
    }
  cv::Mat image(h, w, CV_8UC1);
  std::normal_distribution<double> unit(0, 1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double v = b.ground_level + (b.dot_level - b.ground_level) * coverage.at<float>(y, x);
      if (b.gain_e_per_dn > 0)
        v += unit(rng) *
             std::sqrt(v / b.gain_e_per_dn + std::pow(b.read_noise_e / b.gain_e_per_dn, 2));
      v = std::clamp(std::round(v), 0.0, 255.0);
      image.at<std::uint8_t>(y, x) = static_cast<std::uint8_t>(b.dark_dots ? 255 - v : v);
    }
  return image;
}

}  // namespace storetrack::calib::test
