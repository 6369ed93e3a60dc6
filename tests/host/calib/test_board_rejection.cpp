// Fast rejection of board images without the whole board (issue 9, "Every rejected image or
// point has a reason"; docs/calibration.md, "Fast rejection"). Rendered board images of the
// store separation's four-camera rig with known truth (common/sim), every camera imaging every
// frame of a board set, as tools/calib_stage.py gives them to detect:
//  - every view with some inner corners inside the image and some outside (the board partly
//    outside the frame) is rejected with a reason, each in less than kRejectSecondsBound;
//  - every view the board set counts as whole is kept, and every accepted view has the true
//    corner ids (the nearest true corner of each detected corner is its own);
//  - a board cut by the image edge through its outer squares is "not wholly in view", a board
//    tilted far from the image plane "too oblique"; each beside a control that is accepted.
// The old detector rejected partly visible boards in 2.5-4.0 s and accepted the cut and the
// oblique board.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "storetrack/calib/chessboard_detection.hpp"
#include "storetrack/sim/board_set.hpp"
#include "storetrack/sim/render.hpp"
#include "storetrack/sim/scenario.hpp"
#include "storetrack/sim/simulator.hpp"

namespace storetrack::calib {
namespace {

// Bound on the detection time of one rejected 1920 x 1024 image. Measured (this machine, load
// 2.4-2.8 on its 2 cores; the 119 images without a whole board of the seed-1 board set of
// tools/testpoint): the search took 0.219 s median, 0.595 s at most (two quick searches); the
// bound leaves 2.5x for a loaded CI machine. The old detector took 2.5-4.0 s on 12 of the 14
// partly visible views here (3.4 s median on the seed-1 set). Asserted in Release only.
[[maybe_unused]] constexpr double kRejectSecondsBound = 1.5;

struct Scene {
  camera::RigCalibration rig;
  sim::BoardSetOptions options;
  sim::BoardPhotometry photometry;
  ChessboardSpec spec;
};

Scene store_separation() {
  const sim::Scenario sc =
      sim::load_scenario(std::string(STORETRACK_SIM_SCENARIO_DIR) + "/store_separation.json");
  Scene s;
  s.rig = sim::Simulator(sc, 1).true_rig();
  s.photometry.sensor = sc.optics.sensor;
  s.photometry.psf_sigma_px = sc.optics.psf_sigma_px;
  s.spec = {s.options.board.cols, s.options.board.rows, s.options.board.square_m};
  return s;
}

struct Outcome {
  bool accepted = false;
  std::string reason;
  double seconds = 0;
  int wrong_ids = 0;  ///< detected corners whose nearest true corner is another id
};

// One camera's noisy image of the board at T_c_b through the project's detector, timed.
Outcome detect_view(const Scene& s, const camera::CalibratedCamera& cam,
                    const geometry::Transform& T_c_b, std::uint64_t noise_seed) {
  sim::BoardExpectedImage e;
  sim::render_board_expected(cam.model, T_c_b, s.options.board, s.photometry, e);
  std::vector<std::uint8_t> gray(e.electrons.size());
  std::mt19937_64 rng(noise_seed);
  sim::expose(e.electrons.data(), e.width, s.photometry.sensor, rng, gray.data(), e.width, e.height,
              e.width);
  Outcome out;
  ObservationSet set;
  const auto t0 = std::chrono::steady_clock::now();
  out.accepted = detect_chessboard_image(gray.data(), e.width, e.height, e.width, s.spec,
                                         cam.camera_id, 0, set, &out.reason);
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const auto truth = sim::project_board_corners(cam.model, T_c_b, s.options.board);
  for (const Observation& o : set.observations) {
    int nearest = -1;
    double best = std::numeric_limits<double>::infinity();
    for (std::size_t id = 0; id < truth.size(); ++id) {
      if (truth[id] && (o.pixel - *truth[id]).norm() < best) {
        best = (o.pixel - *truth[id]).norm();
        nearest = static_cast<int>(id);
      }
    }
    out.wrong_ids += nearest == o.point_id ? 0 : 1;
  }
  return out;
}

// Inner corners of the board at T_c_b that project inside the camera's image.
int corners_inside(const Scene& s, const camera::CalibratedCamera& cam,
                   const geometry::Transform& T_c_b) {
  const camera::Intrinsics& in = cam.model.intrinsics();
  int n = 0;
  for (const auto& p : sim::project_board_corners(cam.model, T_c_b, s.options.board)) {
    const bool in_image =
        p && p->x() >= 0 && p->y() >= 0 && p->x() <= in.width - 1 && p->y() <= in.height - 1;
    n += in_image ? 1 : 0;
  }
  return n;
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// A frontal board (board axes along the camera's) at depth z_m, its corner 0 at `pixel`.
geometry::Transform frontal_board(const camera::CalibratedCamera& cam, const geometry::Vec2& pixel,
                                  double z_m) {
  const geometry::Vec2 xy = *cam.model.unproject(pixel);
  geometry::Transform T_c_b = geometry::Transform::Identity();
  T_c_b.translation() = geometry::Vec3(xy.x(), xy.y(), 1.0) * z_m;
  return T_c_b;
}

// Frontal boards 1.5 m from camera 0 (53 px squares) pushed over each image edge, 30 % and 60 %
// of their inner-corner grid outside: partly outside the frame by construction.
std::vector<geometry::Transform> boards_over_the_edges(const Scene& s) {
  const camera::CalibratedCamera& cam = s.rig.cameras[0];
  const double w = cam.model.intrinsics().width, h = cam.model.intrinsics().height;
  const double grid_w = (s.options.board.cols - 1) * 53.0,
               grid_h = (s.options.board.rows - 1) * 53.0;
  std::vector<geometry::Transform> out;
  for (const double f : {0.3, 0.6}) {
    out.push_back(frontal_board(cam, {-f * grid_w, 350}, 1.5));
    out.push_back(frontal_board(cam, {w - 1 - (1 - f) * grid_w, 350}, 1.5));
    out.push_back(frontal_board(cam, {700, -f * grid_h}, 1.5));
    out.push_back(frontal_board(cam, {700, h - 1 - (1 - f) * grid_h}, 1.5));
  }
  return out;
}

// Tally of one run: views by their truth, what the detector made of them, how long it took.
struct Tally {
  int whole = 0, whole_kept = 0, partial = 0, partial_rejected = 0, other = 0, other_accepted = 0,
      wrong_views = 0;
  std::vector<double> t_accepted, t_rejected, t_partial;
};

// Detects one view and checks it against its truth: whole (the board set's limits) -> kept;
// partly outside the frame (its face to the camera, some inner corners inside the image and
// some not) -> rejected with a reason within kRejectSecondsBound; any accepted view -> true ids.
void score_view(const Scene& s, const camera::CalibratedCamera& cam,
                const geometry::Transform& T_c_b, bool is_whole, std::uint64_t noise_seed,
                const std::string& name, Tally& t) {
  const int inside = corners_inside(s, cam, T_c_b);
  const bool is_partial = !is_whole && !sim::sees_board_back(T_c_b) && inside > 0 &&
                          inside < s.options.board.num_corners();
  const Outcome o = detect_view(s, cam, T_c_b, noise_seed);
  (o.accepted ? t.t_accepted : t.t_rejected).push_back(o.seconds);
  if (o.wrong_ids > 0) {
    ++t.wrong_views;
    ADD_FAILURE() << name << ": " << o.wrong_ids << " corner ids are not the true ones";
  }
  EXPECT_TRUE(o.accepted || !o.reason.empty()) << name << ": rejected without a reason";
  if (is_whole) {
    ++t.whole;
    t.whole_kept += o.accepted ? 1 : 0;
    EXPECT_TRUE(o.accepted) << name << " (whole board in view) lost: " << o.reason;
  } else if (is_partial) {
    ++t.partial;
    t.partial_rejected += o.accepted ? 0 : 1;
    t.t_partial.push_back(o.seconds);
    EXPECT_FALSE(o.accepted) << name << " (" << inside << " corners inside) accepted";
#ifndef STORETRACK_SANITIZE  // a Release bound: the sanitizer tree's code is 2-10x slower
    EXPECT_LT(o.seconds, kRejectSecondsBound) << name << ": " << o.reason;
#endif
  } else {
    ++t.other;
    t.other_accepted += o.accepted ? 1 : 0;
  }
}

TEST(BoardRejection, PartlyVisibleBoardsRejectedQuicklyWholeBoardsKept) {
  Scene s = store_separation();
  s.options.common_views = 2;
  s.options.single_views = 2;
  const std::vector<sim::BoardFrame> frames = sim::plan_board_frames(s.rig, s.options, 1);
  Tally t;
  for (const sim::BoardFrame& f : frames) {
    for (const camera::CalibratedCamera& cam : s.rig.cameras) {
      const bool is_whole = std::find(f.cameras_seeing.begin(), f.cameras_seeing.end(),
                                      cam.camera_id) != f.cameras_seeing.end();
      score_view(s, cam, sim::board_in_camera(cam, f), is_whole,
                 sim::board_image_seed(1, f.frame, cam.camera_id),
                 "camera " + std::to_string(cam.camera_id) + " frame " + std::to_string(f.frame),
                 t);
    }
  }
  const std::vector<geometry::Transform> over = boards_over_the_edges(s);
  for (std::size_t k = 0; k < over.size(); ++k) {
    ASSERT_GT(corners_inside(s, s.rig.cameras[0], over[k]), 0);
    ASSERT_LT(corners_inside(s, s.rig.cameras[0], over[k]), s.options.board.num_corners());
    score_view(s, s.rig.cameras[0], over[k], false, 100 + k,
               "board over the edge " + std::to_string(k), t);
  }
  std::printf(
      "%zu frames x %zu cameras + %zu boards over the edges: whole %d (kept %d), partly outside "
      "%d (rejected %d; seconds median %.3f, max %.3f), other %d (back, out of view or beyond "
      "the set's limits; accepted %d); accepted images %.3f s median, rejected %.3f s median; "
      "%d views with wrong ids\n",
      frames.size(), s.rig.cameras.size(), over.size(), t.whole, t.whole_kept, t.partial,
      t.partial_rejected, median(t.t_partial),
      t.t_partial.empty() ? 0 : *std::max_element(t.t_partial.begin(), t.t_partial.end()), t.other,
      t.other_accepted, median(t.t_accepted), median(t.t_rejected), t.wrong_views);
  EXPECT_EQ(t.whole_kept, t.whole);
  EXPECT_EQ(t.partial_rejected, t.partial);
  EXPECT_EQ(t.wrong_views, 0);
  EXPECT_GE(t.partial, 10) << "too few partly visible views: the test would not test them";
}

TEST(BoardRejection, BoardCutThroughItsOuterSquaresIsNotWhollyInView) {
  const Scene s = store_separation();
  const camera::CalibratedCamera& cam = s.rig.cameras[0];
  // 1.2 m away the 80 mm squares are ~67 px: column 0 of the inner corners 24 px from the left
  // edge puts the outer squares 2/3 outside; moved one square right, they are inside (the
  // white border beyond them still cut) and the board is accepted.
  const geometry::Transform cut = frontal_board(cam, {24, 300}, 1.2);
  const geometry::Transform control = frontal_board(cam, {24 + 67, 300}, 1.2);
  ASSERT_EQ(corners_inside(s, cam, cut), s.options.board.num_corners());
  const Outcome c = detect_view(s, cam, cut, 11);
  std::printf("cut: %s (%.3f s)\n", c.accepted ? "accepted" : c.reason.c_str(), c.seconds);
  EXPECT_FALSE(c.accepted);
  EXPECT_EQ(c.reason.rfind("board not wholly in view", 0), 0u) << c.reason;
  const Outcome k = detect_view(s, cam, control, 12);
  EXPECT_TRUE(k.accepted) << k.reason;
  EXPECT_EQ(k.wrong_ids, 0);
}

TEST(BoardRejection, BoardFarFromTheImagePlaneIsTooOblique) {
  const Scene s = store_separation();
  const camera::CalibratedCamera& cam = s.rig.cameras[0];
  // The board's centre 1.6 m ahead on the optical axis, turned about the board's y axis.
  const auto tilted = [&](double deg) {
    geometry::Transform T_c_b = geometry::Transform::Identity();
    T_c_b.linear() =
        Eigen::AngleAxisd(deg * M_PI / 180, geometry::Vec3::UnitY()).toRotationMatrix();
    T_c_b.translation() = geometry::Vec3(0, 0, 1.6) - T_c_b.linear() * s.options.board.centre();
    return T_c_b;
  };
  const Outcome steep = detect_view(s, cam, tilted(68), 13);
  std::printf("68 deg: %s (%.3f s)\n", steep.accepted ? "accepted" : steep.reason.c_str(),
              steep.seconds);
  EXPECT_FALSE(steep.accepted);
  EXPECT_EQ(steep.reason.rfind("board too oblique", 0), 0u) << steep.reason;
  const Outcome control = detect_view(s, cam, tilted(45), 14);
  EXPECT_TRUE(control.accepted) << control.reason;
  EXPECT_EQ(control.wrong_ids, 0);
}

// Small boards tilted across the view (squares ~8 px in the search image) that
// findChessboardCorners without adaptive thresholding misses: the quick search finds them and
// its corners, reversed, carry the true ids. Views of test_calib_board_images' Monte Carlo
// (static scenario, cameras 0 and 1; draws 7 and 18, frame 12, camera 0); the old detector
// lost the second (its adaptive search failed after 4.8 s).
TEST(BoardRejection, SmallTiltedBoardsFoundByTheQuickSearchHaveTrueIds) {
  sim::Scenario sc = sim::load_scenario(std::string(STORETRACK_SIM_SCENARIO_DIR) + "/static.json");
  sc.cameras.resize(2);
  Scene s;
  s.rig = sim::Simulator(sc, 1).true_rig();
  s.photometry.sensor = sc.optics.sensor;
  s.photometry.psf_sigma_px = sc.optics.psf_sigma_px;
  s.spec = {s.options.board.cols, s.options.board.rows, s.options.board.square_m};
  s.options.common_views = 5;
  s.options.single_views = 5;
  const camera::CalibratedCamera& cam = s.rig.cameras[0];
  for (const int draw : {7, 18}) {
    const auto frames =
        sim::plan_board_frames(s.rig, s.options, 21 + static_cast<std::uint64_t>(draw));
    const sim::BoardFrame& f = frames[12];
    ASSERT_NE(std::find(f.cameras_seeing.begin(), f.cameras_seeing.end(), cam.camera_id),
              f.cameras_seeing.end());
    const Outcome o = detect_view(
        s, cam, sim::board_in_camera(cam, f),
        sim::board_image_seed(1000 + static_cast<std::uint64_t>(draw), f.frame, cam.camera_id));
    std::printf("draw %d: %s (%.3f s)\n", draw, o.accepted ? "accepted" : o.reason.c_str(),
                o.seconds);
    EXPECT_TRUE(o.accepted) << "draw " << draw << ": " << o.reason;
    EXPECT_EQ(o.wrong_ids, 0) << "draw " << draw;
  }
}

}  // namespace
}  // namespace storetrack::calib
