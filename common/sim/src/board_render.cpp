// Chessboard images: see board_render.hpp. The pixel -> board map is the inverse of the camera
// model (unproject, then the ray meets the board plane), evaluated exactly on a coarse grid and
// interpolated bilinearly; each pixel's coverage uses the local affine map (value and gradient
// of the interpolation), which is exact for straight edges across the pixel.
#include "storetrack/sim/board_render.hpp"

#include <algorithm>
#include <cmath>

namespace storetrack::sim {
namespace {

using geometry::Vec2;
using geometry::Vec3;

constexpr int kGridStepPx = 4;
constexpr int kCornerSamples = 16;  // per axis, pixels cut by two or more edges

// Fraction of a pixel where U < t, with U = U0 + gx xi + gy eta over the pixel
// (xi, eta uniform on [-1/2, 1/2]): the CDF of the sum of two uniforms (trapezoidal density),
// z = t - U0.
double fraction_below(double z, double gx, double gy) {
  double a = std::abs(gx), b = std::abs(gy);
  if (a < b) std::swap(a, b);
  if (a <= 0) return z > 0 ? 1.0 : 0.0;
  const double h1 = (a - b) / 2, h2 = (a + b) / 2;
  if (z <= -h2) return 0.0;
  if (z >= h2) return 1.0;
  if (b < 1e-9 * a) return std::clamp(0.5 + z / a, 0.0, 1.0);
  if (z < -h1) return (z + h2) * (z + h2) / (2 * a * b);
  if (z <= h1) return 0.5 + z / a;
  return 1.0 - (h2 - z) * (h2 - z) / (2 * a * b);
}

// Board map on grid nodes at pixel centres (kGridStepPx apart): board (x, y) in squares, or NaN
// where the ray misses the board plane in front of the camera or unprojection fails.
struct BoardMap {
  int nx = 0, ny = 0;
  std::vector<Vec2> uv;  // row-major nx x ny
};

BoardMap map_board(const camera::CameraModel& camera, const geometry::Transform& T_c_b,
                   double square_m) {
  const camera::Intrinsics& in = camera.intrinsics();
  BoardMap map;
  map.nx = (in.width - 1) / kGridStepPx + 2;
  map.ny = (in.height - 1) / kGridStepPx + 2;
  map.uv.assign(static_cast<std::size_t>(map.nx) * map.ny, Vec2::Constant(NAN));
  // Plane-induced homography: ray d ~ [r1 r2 t] (x_b, y_b, 1), so (x_b, y_b, 1) ~ H^-1 d.
  geometry::Mat3 H;
  H.col(0) = T_c_b.linear().col(0);
  H.col(1) = T_c_b.linear().col(1);
  H.col(2) = T_c_b.translation();
  const geometry::Mat3 H_inv = H.inverse();
  for (int j = 0; j < map.ny; ++j) {
    for (int i = 0; i < map.nx; ++i) {
      const auto xy = camera.unproject(Vec2(i * kGridStepPx, j * kGridStepPx), 1e-7, 30);
      if (!xy) continue;
      const Vec3 d(xy->x(), xy->y(), 1.0);
      const Vec3 b = H_inv * d;
      // The ray's depth at the plane is 1 / b.z() (d = lambda H b with lambda b.z() = 1 for the
      // homogeneous board point): behind the camera when negative.
      if (!(b.z() > 0)) continue;
      map.uv[static_cast<std::size_t>(j) * map.nx + i] = Vec2(b.x(), b.y()) / (b.z() * square_m);
    }
  }
  return map;
}

class Pattern {
 public:
  // `back`: the camera sees the board's back, which is opaque and plain (a real board's
  // pattern is not seen through it, nor mirrored): the whole board is the border's white.
  Pattern(const ChessboardTarget& board, const BoardPhotometry& ph, bool back)
      : b_(board), ph_(ph), back_(back) {}
  // Signal of board cell (i, j) (square units; inner corner (c, r) at (c, r)).
  double at(long i, long j) const {
    const long m = b_.margin_squares;
    if (i < -1 - m || i > b_.cols - 1 + m || j < -1 - m || j > b_.rows - 1 + m)
      return ph_.surround_e;
    if (back_ || i < -1 || i > b_.cols - 1 || j < -1 || j > b_.rows - 1) return ph_.white_e;
    // The square whose top-left corner is inner corner 0 (cell (0, 0)) is black.
    return ((i + j) % 2 == 0) ? ph_.black_e : ph_.white_e;
  }

 private:
  const ChessboardTarget& b_;
  const BoardPhotometry& ph_;
  bool back_;
};

long cell(double u) {
  return static_cast<long>(std::floor(u));
}

// Mean signal over one pixel whose board map is U = u + ux dx + uy dy (dx, dy in pixels from
// its centre), likewise V.
double pixel_signal(const Pattern& pattern, double u, double v, double ux, double uy, double vx,
                    double vy) {
  const double eu = (std::abs(ux) + std::abs(uy)) / 2, ev = (std::abs(vx) + std::abs(vy)) / 2;
  const long i0 = cell(u - eu), i1 = cell(u + eu), j0 = cell(v - ev), j1 = cell(v + ev);
  if (i0 == i1 && j0 == j1) return pattern.at(i0, j0);
  if (i1 == i0 + 1 && j0 == j1) {
    const double f = fraction_below(static_cast<double>(i1) - u, ux, uy);
    return f * pattern.at(i0, j0) + (1 - f) * pattern.at(i1, j0);
  }
  if (j1 == j0 + 1 && i0 == i1) {
    const double f = fraction_below(static_cast<double>(j1) - v, vx, vy);
    return f * pattern.at(i0, j0) + (1 - f) * pattern.at(i0, j1);
  }
  double sum = 0;
  for (int sy = 0; sy < kCornerSamples; ++sy) {
    const double dy = (sy + 0.5) / kCornerSamples - 0.5;
    for (int sx = 0; sx < kCornerSamples; ++sx) {
      const double dx = (sx + 0.5) / kCornerSamples - 0.5;
      sum += pattern.at(cell(u + ux * dx + uy * dy), cell(v + vx * dx + vy * dy));
    }
  }
  return sum / (kCornerSamples * kCornerSamples);
}

// The signal of a whole grid cell (kGridStepPx square) when every pixel of it lies in one
// pattern value: the cell's board map is bilinear, so its range is that of the four nodes, padded
// by the half pixel the outer pixels reach beyond the nodes. NaN when not constant.
double constant_cell_signal(const Pattern& pattern, const ChessboardTarget& board, const Vec2& p00,
                            const Vec2& p10, const Vec2& p01, const Vec2& p11) {
  const Vec2 lo = p00.cwiseMin(p10).cwiseMin(p01.cwiseMin(p11));
  const Vec2 hi = p00.cwiseMax(p10).cwiseMax(p01.cwiseMax(p11));
  const Vec2 pad = (hi - lo) * (0.5 / kGridStepPx) + Vec2::Constant(1e-9);
  const long i0 = cell(lo.x() - pad.x()), i1 = cell(hi.x() + pad.x());
  const long j0 = cell(lo.y() - pad.y()), j1 = cell(hi.y() + pad.y());
  if (i0 == i1 && j0 == j1) return pattern.at(i0, j0);
  const long m = board.margin_squares;
  const bool outside =
      i1 < -1 - m || i0 > board.cols - 1 + m || j1 < -1 - m || j0 > board.rows - 1 + m;
  return outside ? pattern.at(i0, j0) : NAN;
}

void render_signal(const BoardMap& map, const Pattern& pattern, const ChessboardTarget& board,
                   double surround, int width, int height, std::vector<float>& out) {
  out.assign(static_cast<std::size_t>(width) * height, static_cast<float>(surround));
  const double inv_g = 1.0 / kGridStepPx;
  for (int j = 0; j * kGridStepPx < height; ++j) {
    for (int i = 0; i * kGridStepPx < width; ++i) {
      const std::size_t n00 = static_cast<std::size_t>(j) * map.nx + i;
      const Vec2& p00 = map.uv[n00];
      const Vec2& p10 = map.uv[n00 + 1];
      const Vec2& p01 = map.uv[n00 + map.nx];
      const Vec2& p11 = map.uv[n00 + map.nx + 1];
      if (!(p00.allFinite() && p10.allFinite() && p01.allFinite() && p11.allFinite())) continue;
      const int x_end = std::min(width, (i + 1) * kGridStepPx);
      const int y_end = std::min(height, (j + 1) * kGridStepPx);
      const double constant = constant_cell_signal(pattern, board, p00, p10, p01, p11);
      for (int y = j * kGridStepPx; y < y_end; ++y) {
        const double fy = (y - j * kGridStepPx) * inv_g;
        float* row = out.data() + static_cast<std::size_t>(y) * width;
        if (!std::isnan(constant)) {
          std::fill(row + i * kGridStepPx, row + x_end, static_cast<float>(constant));
          continue;
        }
        for (int x = i * kGridStepPx; x < x_end; ++x) {
          const double fx = (x - i * kGridStepPx) * inv_g;
          const Vec2 top = p00 + fx * (p10 - p00), bottom = p01 + fx * (p11 - p01);
          const Vec2 uv = top + fy * (bottom - top);
          const Vec2 d_dx = ((1 - fy) * (p10 - p00) + fy * (p11 - p01)) * inv_g;
          const Vec2 d_dy = (bottom - top) * inv_g;
          row[x] = static_cast<float>(
              pixel_signal(pattern, uv.x(), uv.y(), d_dx.x(), d_dy.x(), d_dx.y(), d_dy.y()));
        }
      }
    }
  }
}

// Separable Gaussian blur (sampled kernel, normalised; edges clamped).
void blur(std::vector<float>& image, int width, int height, double sigma) {
  if (!(sigma > 0.05)) return;
  const int radius = static_cast<int>(std::ceil(4 * sigma));
  std::vector<float> kernel(static_cast<std::size_t>(2 * radius + 1));
  double sum = 0;
  for (int k = -radius; k <= radius; ++k) {
    const double w = std::exp(-0.5 * k * k / (sigma * sigma));
    kernel[static_cast<std::size_t>(k + radius)] = static_cast<float>(w);
    sum += w;
  }
  for (float& w : kernel)
    w = static_cast<float>(w / sum);
  std::vector<float> tmp(image.size());
  for (int y = 0; y < height; ++y) {
    const float* row = image.data() + static_cast<std::size_t>(y) * width;
    float* dst = tmp.data() + static_cast<std::size_t>(y) * width;
    for (int x = 0; x < width; ++x) {
      float acc = 0;
      if (x >= radius && x + radius < width) {
        const float* src = row + x - radius;
        for (int k = 0; k <= 2 * radius; ++k)
          acc += kernel[static_cast<std::size_t>(k)] * src[k];
      } else {
        for (int k = -radius; k <= radius; ++k)
          acc +=
              kernel[static_cast<std::size_t>(k + radius)] * row[std::clamp(x + k, 0, width - 1)];
      }
      dst[x] = acc;
    }
  }
  for (int y = 0; y < height; ++y) {
    float* dst = image.data() + static_cast<std::size_t>(y) * width;
    for (int x = 0; x < width; ++x)
      dst[x] = 0;
    for (int k = -radius; k <= radius; ++k) {
      const float w = kernel[static_cast<std::size_t>(k + radius)];
      const float* src =
          tmp.data() + static_cast<std::size_t>(std::clamp(y + k, 0, height - 1)) * width;
      for (int x = 0; x < width; ++x)
        dst[x] += w * src[x];
    }
  }
}

}  // namespace

std::vector<Vec3> ChessboardTarget::outline() const {
  const double m = (margin_squares + 1) * square_m;
  const double x1 = (cols - 1) * square_m + m, y1 = (rows - 1) * square_m + m;
  return {Vec3(-m, -m, 0), Vec3(x1, -m, 0), Vec3(x1, y1, 0), Vec3(-m, y1, 0)};
}

void render_board_expected(const camera::CameraModel& camera, const geometry::Transform& T_c_b,
                           const ChessboardTarget& board, const BoardPhotometry& photometry,
                           BoardExpectedImage& out) {
  const int width = camera.intrinsics().width, height = camera.intrinsics().height;
  out.width = width;
  out.height = height;
  const BoardMap map = map_board(camera, T_c_b, board.square_m);
  render_signal(map, Pattern(board, photometry, sees_board_back(T_c_b)), board,
                photometry.surround_e, width, height, out.electrons);
  blur(out.electrons, width, height, photometry.psf_sigma_px);
  const float background = static_cast<float>(photometry.sensor.background_e);
  for (float& e : out.electrons)
    e += background;
}

std::vector<std::optional<Vec2>> project_board_corners(const camera::CameraModel& camera,
                                                       const geometry::Transform& T_c_b,
                                                       const ChessboardTarget& board) {
  std::vector<std::optional<Vec2>> out;
  out.reserve(static_cast<std::size_t>(board.num_corners()));
  for (int id = 0; id < board.num_corners(); ++id)
    out.push_back(camera.project(T_c_b * board.corner(id)));
  return out;
}

bool sees_board_back(const geometry::Transform& T_c_b) {
  // The pattern faces -z_b (board z points away from the cameras that see it): the camera
  // centre, at -R^T t in the board frame, is on the back when its z is positive.
  return (T_c_b.inverse().translation()).z() > 0;
}

double board_incidence_deg(const geometry::Transform& T_c_b, const ChessboardTarget& board) {
  const Vec3 centre_c = T_c_b * board.centre();
  const double cos_incidence = T_c_b.linear().col(2).dot(centre_c.normalized());
  return std::acos(std::clamp(cos_incidence, -1.0, 1.0)) * 180 / M_PI;
}

bool board_fully_visible(const camera::CameraModel& camera, const geometry::Transform& T_c_b,
                         const ChessboardTarget& board, double margin_px, double min_square_px,
                         double max_incidence_deg) {
  if (sees_board_back(T_c_b)) return false;
  const camera::Intrinsics& in = camera.intrinsics();
  const auto inside = [&](const Vec3& p_b) {
    const auto px = camera.project(T_c_b * p_b);
    return px && px->x() >= margin_px && px->x() <= in.width - 1 - margin_px &&
           px->y() >= margin_px && px->y() <= in.height - 1 - margin_px;
  };
  // The outline, densely: distortion bends its edges.
  const std::vector<Vec3> outline = board.outline();
  for (std::size_t k = 0; k < outline.size(); ++k) {
    const Vec3& a = outline[k];
    const Vec3& b = outline[(k + 1) % outline.size()];
    for (int s = 0; s < 32; ++s) {
      if (!inside(a + (b - a) * (s / 32.0))) return false;
    }
  }
  const auto corners = project_board_corners(camera, T_c_b, board);
  for (int id = 0; id < board.num_corners(); ++id) {
    const int col = id % board.cols, row = id / board.cols;
    const auto& p = corners[static_cast<std::size_t>(id)];
    if (!p) return false;
    if (col + 1 < board.cols &&
        (*p - *corners[static_cast<std::size_t>(id + 1)]).norm() < min_square_px)
      return false;
    if (row + 1 < board.rows &&
        (*p - *corners[static_cast<std::size_t>(id + board.cols)]).norm() < min_square_px)
      return false;
  }
  return board_incidence_deg(T_c_b, board) <= max_incidence_deg;
}

}  // namespace storetrack::sim
