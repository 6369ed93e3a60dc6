// Dot grids with known truth (dot_grid_rendering.hpp): indexing must be exactly right and each
// centroid within a derived bound of the imaged circle's centre; bad boards are refused with
// a reason naming the image.
#include <gtest/gtest.h>

#include <map>
#include <random>

#include "dot_grid_rendering.hpp"
#include "storetrack/calib/dot_grid_detection.hpp"

namespace storetrack::calib {
namespace {

constexpr int kWidth = 1280, kHeight = 960;
/// Rendering error of a centroid: the 8x supersampled 256-gon's coverage (edge digitised to
/// 1/8 px: ~2e-3 px on a 10 px dot) and the 8-bit rounding of edge pixels (<= 0.5 DN of 200
/// on ~2 pi R edge pixels: 0.5 / 200 * 2 pi R^2 / (pi R^2) = 0.005 px), with margin.
constexpr double kRenderBoundPx = 0.02;
/// Per-axis noise bound in centroid sigmas: P(|N(0,1)| > 5) = 5.7e-7 per axis, so over the
/// <= 400 coordinates of a test < 2.3e-4 that a correct centroider fails.
constexpr double kSigmas = 5.0;

/// A pinhole camera (f 1400 px) looking at the board plane tilted about x and y.
Eigen::Matrix3d board_to_image(double tilt_x_deg, double tilt_y_deg, double distance,
                               const Eigen::Vector2d& board_centre, double roll_deg = 8) {
  Eigen::Matrix3d K;
  K << 1400, 0, 640, 0, 1400, 480, 0, 0, 1;
  const Eigen::Matrix3d R = (Eigen::AngleAxisd(tilt_x_deg * M_PI / 180, Eigen::Vector3d::UnitX()) *
                             Eigen::AngleAxisd(tilt_y_deg * M_PI / 180, Eigen::Vector3d::UnitY()) *
                             Eigen::AngleAxisd(roll_deg * M_PI / 180, Eigen::Vector3d::UnitZ()))
                                .toRotationMatrix();
  // The board's y axis points up in the image (mathematical axes on the print): flip y.
  Eigen::Matrix3d flip = Eigen::Vector3d(1, -1, 1).asDiagonal();
  Eigen::Matrix3d M;
  M.col(0) = (R * flip).col(0);
  M.col(1) = (R * flip).col(1);
  M.col(2) = Eigen::Vector3d(0, 0, distance) - (R * flip).leftCols<2>() * board_centre;
  return K * M;
}

GrayImageView view_of(const cv::Mat& m, const std::string& name) {
  return {name, m.data, m.cols, m.rows, static_cast<int>(m.step)};
}

struct Scored {
  int indexed = 0, wrong_index = 0, outside_bound = 0, rings = 0;
  int clear = 0, inside = 0;  // model dots clear of the image edge (patch too) / inside it
  double max_error_px = 0, rms_over_sigma = 0, max_bias_px = 0;
};

/// Matches each observation to the rendered dot nearest to it; scores index and centre.
Scored score(const DotDetectionResult& r, const std::vector<test::RenderedDot>& truth, int cols,
             int min_col = 0, int min_row = 0, int max_col = 1 << 20, int max_row = 1 << 20) {
  Scored s;
  double sum_sq = 0;
  for (const auto& o : r.set.observations) {
    const test::RenderedDot* nearest = nullptr;
    for (const auto& t : truth)
      if (!nearest ||
          (t.ellipse_centre - o.pixel).norm() < (nearest->ellipse_centre - o.pixel).norm())
        nearest = &t;
    ++s.indexed;
    if (nearest->row * cols + nearest->col != o.point_id) ++s.wrong_index;
    const Eigen::Vector2d e = o.pixel - nearest->ellipse_centre;
    const double sigma = o.sigma_px.value_or(0);
    // A ring dot is two ellipses whose centres differ by the perspective bias of each, so it
    // is not point-symmetric: no closed-form centre; counted, not scored.
    if (nearest->ring) {
      ++s.rings;
      continue;
    }
    if (std::abs(e.x()) > kRenderBoundPx + kSigmas * sigma ||
        std::abs(e.y()) > kRenderBoundPx + kSigmas * sigma)
      ++s.outside_bound;
    s.max_error_px = std::max(s.max_error_px, e.cwiseAbs().maxCoeff());
    sum_sq += e.squaredNorm() / (2 * sigma * sigma);
    s.max_bias_px =
        std::max(s.max_bias_px, (nearest->ellipse_centre - nearest->projected_centre).norm());
  }
  for (const auto& t : truth)
    if (t.col >= min_col && t.row >= min_row && t.col <= max_col && t.row <= max_row) {
      s.clear += t.clear;
      s.inside += t.inside;
    }
  s.rms_over_sigma = s.indexed > s.rings ? std::sqrt(sum_sq / (s.indexed - s.rings)) : 0;
  return s;
}

// The ring-dot board of DICe's layout on a 14 x 10 board larger than the view: origin (2, 2),
// x marker 6 and y marker 4 dots from it; dark dots on white, the model 12 x 9 of it.
test::DotBoardRender ring_board() {
  test::DotBoardRender b;
  b.cols = 14, b.rows = 10, b.spacing = 40, b.radius = 9, b.hole_radius = 3;
  b.rings = {{2, 2}, {7, 2}, {2, 5}};
  b.dark_dots = true;
  return b;
}

DotGridSpec ring_spec() {
  DotGridSpec spec;
  spec.kind = DotBoardKind::kRingDots;
  spec.cols = 12, spec.rows = 9, spec.spacing_m = 0.040;
  spec.origin_col = 2, spec.origin_row = 2, spec.origin_to_x_marker = 6,
  spec.origin_to_y_marker = 4;
  return spec;
}

TEST(DotGridSynthetic, RingDotsLargerThanTheViewIndexedExactly) {
  std::mt19937_64 rng(7);
  const test::DotBoardRender board = ring_board();
  const DotGridSpec spec = ring_spec();
  int total_expected = 0;
  for (const auto& [tx, ty, dist] : std::vector<std::array<double, 3>>{
           {25, -20, 420}, {-35, 15, 380}, {10, 30, 450}, {0, 0, 400}}) {
    const Eigen::Matrix3d H = board_to_image(tx, ty, dist, {4.5 * 40, 4.5 * 40});
    std::vector<test::RenderedDot> truth;
    const cv::Mat image = render_dot_board(H, board, kWidth, kHeight, truth, rng);
    const DotDetectionResult r =
        detect_dot_grids(std::vector<GrayImageView>{view_of(image, "synthetic.png")}, spec, {}, 0);
    ASSERT_EQ(r.images_used, 1) << (r.rejected.empty() ? "" : r.rejected[0].reason);
    const Scored s = score(r, truth, spec.cols, 0, 0, spec.cols - 1, spec.rows - 1);
    std::printf(
        "tilt (%g, %g) deg: %d dots indexed (model dots clear of the edge %d, inside "
        "%d), wrong %d, max error %.4f px, rms error / sigma %.2f (%d ring dots not "
        "scored), perspective bias up to %.4f px\n",
        tx, ty, s.indexed, s.clear, s.inside, s.wrong_index, s.max_error_px, s.rms_over_sigma,
        s.rings, s.max_bias_px);
    EXPECT_EQ(s.wrong_index, 0);
    // Every model dot whose refinement patch is in view, none that is cut by the edge.
    EXPECT_GE(s.indexed, s.clear);
    EXPECT_LE(s.indexed, s.inside);
    EXPECT_EQ(s.outside_bound, 0);
    EXPECT_EQ(s.rings, 3);
    total_expected += s.clear;
    if (s.indexed < s.clear)
      for (const auto& d : r.rejected_dots)
        std::printf("  not used (%.1f, %.1f): %s\n", d.pixel.x(), d.pixel.y(), d.reason.c_str());
    // Dots outside the model are named as such.
    int outside_model = 0;
    for (const auto& d : r.rejected_dots)
      outside_model += d.reason.find("outside the 12x9 grid model") != std::string::npos;
    int clear_outside_model = 0, inside_outside_model = 0;
    for (const auto& t : truth) {
      const bool outside = t.col >= spec.cols || t.row >= spec.rows;
      clear_outside_model += t.clear && outside;
      inside_outside_model += t.inside && outside;
    }
    EXPECT_GE(outside_model, clear_outside_model);
    EXPECT_LE(outside_model, inside_outside_model);
  }
  EXPECT_GT(total_expected, 200);
}

TEST(DotGridSynthetic, FullDotGridLightDotsIndexedExactly) {
  std::mt19937_64 rng(11);
  test::DotBoardRender board;
  board.cols = 9, board.rows = 6, board.spacing = 30, board.radius = 8;
  DotGridSpec spec;
  spec.kind = DotBoardKind::kDots;
  spec.cols = 9, spec.rows = 6, spec.spacing_m = 0.030, spec.dark_dots = false;
  const Eigen::Matrix3d H = board_to_image(20, -25, 500, {4 * 30, 2.5 * 30}, 3);
  std::vector<test::RenderedDot> truth;
  const cv::Mat image = render_dot_board(H, board, kWidth, kHeight, truth, rng);
  const DotDetectionResult r =
      detect_dot_grids(std::vector<GrayImageView>{view_of(image, "grid.png")}, spec, {}, 3);
  ASSERT_EQ(r.images_used, 1) << (r.rejected.empty() ? "" : r.rejected[0].reason);
  Scored s = score(r, truth, board.cols);
  // The grid's naming is OpenCV's (from the image's top-left): the board's truth naming up to a
  // symmetry of the rectangle (coplanar points: a mirror is a rigid 180-degree turn of the
  // board, so every naming calibrates alike). Exactly one symmetry must name all points.
  int best_wrong = s.indexed;
  for (int flip_col = 0; flip_col < 2; ++flip_col)
    for (int flip_row = 0; flip_row < 2; ++flip_row) {
      int wrong = 0;
      for (const auto& o : r.set.observations) {
        const test::RenderedDot* nearest = &truth[0];
        for (const auto& t : truth)
          if ((t.ellipse_centre - o.pixel).norm() < (nearest->ellipse_centre - o.pixel).norm())
            nearest = &t;
        const int col = flip_col ? board.cols - 1 - nearest->col : nearest->col;
        const int row = flip_row ? board.rows - 1 - nearest->row : nearest->row;
        wrong += row * board.cols + col != o.point_id;
      }
      best_wrong = std::min(best_wrong, wrong);
    }
  s.wrong_index = best_wrong;
  std::printf("full grid: %d dots, wrong %d, max error %.4f px, rms error / sigma %.2f\n",
              s.indexed, s.wrong_index, s.max_error_px, s.rms_over_sigma);
  EXPECT_EQ(s.indexed, 54);
  EXPECT_EQ(s.clear, 54);
  EXPECT_EQ(s.wrong_index, 0);
  EXPECT_EQ(s.outside_bound, 0);
  for (const auto& o : r.set.observations)
    EXPECT_EQ(o.camera, 3);
}

// The centroid is the imaged circle's centre, not the projected centre: at this tilt and dot
// size the difference (the perspective bias) must be resolved by the test's bound.
TEST(DotGridSynthetic, CentroidIsTheEllipseCentreNotTheProjectedCentre) {
  std::mt19937_64 rng(3);
  test::DotBoardRender board = ring_board();
  board.radius = 12, board.hole_radius = 4, board.gain_e_per_dn = 0;  // big dots, no noise
  const Eigen::Matrix3d H = board_to_image(40, 0, 500, {4.5 * 40, 4.5 * 40}, 0);
  std::vector<test::RenderedDot> truth;
  const cv::Mat image = render_dot_board(H, board, kWidth, kHeight, truth, rng);
  const DotDetectionResult r = detect_dot_grids(
      std::vector<GrayImageView>{view_of(image, "tilted.png")}, ring_spec(), {}, 0);
  ASSERT_EQ(r.images_used, 1) << (r.rejected.empty() ? "" : r.rejected[0].reason);
  double worst_to_ellipse = 0, worst_to_projected = 0;
  for (const auto& o : r.set.observations) {
    const auto& t = truth[static_cast<size_t>((o.point_id / 12) * board.cols + o.point_id % 12)];
    if (t.ring) continue;  // not point-symmetric (see score())
    worst_to_ellipse = std::max(worst_to_ellipse, (o.pixel - t.ellipse_centre).norm());
    worst_to_projected = std::max(worst_to_projected, (o.pixel - t.projected_centre).norm());
  }
  std::printf(
      "40 deg tilt, 24 mm dots at 40 mm: centroid - ellipse centre <= %.4f px, "
      "centroid - projected centre up to %.4f px\n",
      worst_to_ellipse, worst_to_projected);
  EXPECT_LT(worst_to_ellipse, kRenderBoundPx * std::sqrt(2.0));
  EXPECT_GT(worst_to_projected, 5 * kRenderBoundPx);
}

DotDetectionResult detect_rings(const std::vector<std::pair<int, int>>& rings, bool mirror,
                                const std::string& name) {
  std::mt19937_64 rng(5);
  test::DotBoardRender board = ring_board();
  board.rings = rings;
  const Eigen::Matrix3d H = board_to_image(15, 10, 420, {4.5 * 40, 4.5 * 40});
  std::vector<test::RenderedDot> truth;
  cv::Mat image = render_dot_board(H, board, kWidth, kHeight, truth, rng);
  if (mirror) cv::flip(image, image, 1);
  return detect_dot_grids(std::vector<GrayImageView>{view_of(image, name)}, ring_spec(), {}, 0);
}

void expect_rejected(const DotDetectionResult& r, const std::string& name,
                     const std::string& reason) {
  EXPECT_EQ(r.images_used, 0);
  ASSERT_EQ(r.rejected.size(), 1u);
  EXPECT_EQ(r.rejected[0].path, name);
  EXPECT_NE(r.rejected[0].reason.find(reason), std::string::npos) << r.rejected[0].reason;
  EXPECT_TRUE(r.set.observations.empty());
}

TEST(DotGridSynthetic, BadMarkersAreRefusedWithTheImageNamed) {
  expect_rejected(detect_rings({}, false, "no_markers.png"), "no_markers.png",
                  "no ring (marker) dots found");
  expect_rejected(detect_rings({{2, 2}, {7, 2}}, false, "two.png"), "two.png",
                  "found 2 ring (marker) dots, need exactly 3");
  expect_rejected(detect_rings({{2, 2}, {7, 2}, {2, 5}, {5, 4}}, false, "four.png"), "four.png",
                  "found 4 ring (marker) dots");
  expect_rejected(detect_rings({{2, 2}, {7, 2}, {2, 5}}, true, "mirrored.png"), "mirrored.png",
                  "ring dots mirrored");
  // Markers not where the model says (x marker 4 dots from the origin instead of 6).
  expect_rejected(detect_rings({{2, 2}, {5, 2}, {2, 5}}, false, "misplaced.png"), "misplaced.png",
                  "do not fit the grid model");
  // The image the rendering is correct for passes (the same code path).
  EXPECT_EQ(detect_rings({{2, 2}, {7, 2}, {2, 5}}, false, "good.png").images_used, 1);
}

TEST(DotGridSynthetic, FullGridNotInViewIsRefusedWithTheImageNamed) {
  std::mt19937_64 rng(13);
  test::DotBoardRender board;
  board.cols = 9, board.rows = 6, board.spacing = 30, board.radius = 8;
  DotGridSpec spec;
  spec.kind = DotBoardKind::kDots;
  spec.cols = 9, spec.rows = 6, spec.spacing_m = 0.030, spec.dark_dots = false;
  // Shifted so that two columns leave the image.
  const Eigen::Matrix3d H = board_to_image(0, 0, 500, {7.5 * 30, 2.5 * 30}, 0);
  std::vector<test::RenderedDot> truth;
  const cv::Mat image = render_dot_board(H, board, kWidth, kHeight, truth, rng);
  expect_rejected(
      detect_dot_grids(std::vector<GrayImageView>{view_of(image, "cut.png")}, spec, {}, 0),
      "cut.png", "no 9x6 dot grid among");
}

}  // namespace
}  // namespace storetrack::calib
