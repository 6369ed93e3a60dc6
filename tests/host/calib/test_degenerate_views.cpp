// Degenerate views (issue 28): views whose corners lie on one board column or row, on one line
// but one, too few points, or a board seen edge-on give no homography. Before, Zhang's start was
// NaN and `intrinsic` and `rig` stopped with Ceres's "ParameterBlock ... nan nan", naming neither
// camera nor view. Now each is named (camera, frame, reason) and skipped, the calibration from
// the remaining views is the one without them, and nothing usable left is exit 2.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <sstream>

#include "calib_commands.hpp"
#include "storetrack/calib/rig_calibration.hpp"
#include "synthetic_board.hpp"

namespace storetrack::calib {
namespace {

using test::kCols;

std::string temp_path(const std::string& name) {
  return (std::filesystem::temp_directory_path() / ("storetrack_degenerate_" + name)).string();
}

/// Board views of `camera` (the truth camera `offset_m` right of camera 0) for `frames`, only
/// the points `keep` accepts (by point id; row * kCols + col).
void add_views(ObservationSet& set, int camera, const std::vector<int>& frames,
               std::mt19937_64& rng, const std::function<bool(int)>& keep = {},
               double offset_m = 0) {
  const camera::CameraModel model(test::truth_camera());
  std::normal_distribution<double> noise(0, 0.3);
  geometry::Transform T_c_c0 = geometry::Transform::Identity();
  T_c_c0.translation() = geometry::Vec3(-offset_m, 0, 0);
  set.image_sizes[camera] = {1920, 1024};
  ObservationSet all;
  for (int i : frames)
    test::add_board_view(model, T_c_c0 * test::board_pose(i, false), camera, i, noise, rng, all);
  for (const Observation& o : all.observations)
    if (!keep || keep(o.point_id)) set.observations.push_back(o);
}

/// The board seen edge-on: its plane holds the optical axis, every corner on the row y = cy.
void add_edge_on_view(ObservationSet& set, int camera, int frame, std::mt19937_64& rng) {
  geometry::Transform T = geometry::Transform::Identity();
  T.linear() = Eigen::AngleAxisd(M_PI / 2, geometry::Vec3::UnitX()).toRotationMatrix();
  T.translation() = geometry::Vec3(-0.225, 0, 1.4);
  std::normal_distribution<double> noise(0, 0.3);
  test::add_board_view(camera::CameraModel(test::truth_camera()), T, camera, frame, noise, rng,
                       set);
}

ObservationSet without_frames(ObservationSet set, int first_bad) {
  std::erase_if(set.observations,
                [first_bad](const Observation& o) { return o.frame >= first_bad; });
  return set;
}

std::vector<int> range(int first, int end) {
  std::vector<int> out;
  for (int i = first; i < end; ++i)
    out.push_back(i);
  return out;
}

bool column_3(int id) {
  return id % kCols == 3;
}
bool row_2(int id) {
  return id / kCols == 2;
}
bool column_5_and_one(int id) {
  return id % kCols == 5 || id == 0;
}
bool three_points(int id) {
  return id < 3;
}

/// Camera 0: 8 good views (frames 0-7) and one of each degenerate kind (frames 100-104).
ObservationSet intrinsic_set_with_degenerate_views() {
  std::mt19937_64 rng(28);
  ObservationSet set;
  add_views(set, 0, range(0, 8), rng);
  add_views(set, 0, {8}, rng, column_3);
  add_views(set, 0, {9}, rng, row_2);
  add_views(set, 0, {10}, rng, column_5_and_one);
  add_views(set, 0, {11}, rng, three_points);
  for (Observation& o : set.observations)
    if (o.frame >= 8) o.frame += 92;  // frames 100-103: bad ones apart from the good
  add_edge_on_view(set, 0, 104, rng);
  return set;
}

void expect_same_parameters(const camera::Intrinsics& a, const camera::Intrinsics& b) {
  const camera::IntrinsicVector pa = camera::pack(a), pb = camera::pack(b);
  for (int k = 0; k < pa.size(); ++k)
    EXPECT_NEAR(pa[k], pb[k], 1e-9 * std::max(1.0, std::abs(pb[k]))) << "parameter " << k;
}

bool contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

TEST(DegenerateViews, IntrinsicSkipsEachNamedAndMatchesTheFitWithoutThem) {
  const ObservationSet set = intrinsic_set_with_degenerate_views();
  const IntrinsicResult r = calibrate_intrinsics(set, 0, IntrinsicOptions{});
  ASSERT_EQ(r.views_skipped.size(), 5u);
  const auto& s = r.views_skipped;
  EXPECT_EQ(s[0].frame, 100);
  EXPECT_EQ(s[0].reason,
            "all 7 points on one board column (x = 0.15 m): no homography from collinear points");
  EXPECT_EQ(s[1].frame, 101);
  EXPECT_EQ(s[1].reason,
            "all 10 points on one board row (y = 0.1 m): no homography from collinear points");
  EXPECT_EQ(s[2].frame, 102);
  EXPECT_EQ(s[2].reason,
            "7 of its 8 points on one board column (x = 0.25 m) and one off it: a homography "
            "needs 4 points, no 3 of them on one line");
  EXPECT_EQ(s[3].frame, 103);
  EXPECT_EQ(s[3].reason, "3 points, a homography needs >= 4");
  EXPECT_EQ(s[4].frame, 104);
  EXPECT_TRUE(contains(s[4].reason, "its 70 pixels lie within 0.")) << s[4].reason;
  EXPECT_TRUE(contains(s[4].reason, " px (RMS) of one line: the board is seen edge-on"))
      << s[4].reason;

  const IntrinsicResult good = calibrate_intrinsics(without_frames(set, 100), 0, {});
  EXPECT_EQ(r.views.size(), 8u);
  expect_same_parameters(r.intrinsics, good.intrinsics);
  // And the fit is the truth's: fx within 5 of its sigma.
  EXPECT_LT(std::abs(r.intrinsics.fx - test::truth_camera().fx), 5 * std::sqrt(r.covariance(0, 0)));
}

TEST(DegenerateViews, IntrinsicWithNoUsableViewRefusedNamingEach) {
  std::mt19937_64 rng(2);
  ObservationSet set;
  add_views(set, 0, range(0, 6), rng, column_3);
  try {
    calibrate_intrinsics(set, 0, IntrinsicOptions{});
    ADD_FAILURE() << "accepted";
  } catch (const CalibrationError& e) {
    const std::string what = e.what();
    EXPECT_TRUE(contains(what,
                         "camera 0: too few usable views: 0 board poses, need at least 3 (6 "
                         "skipped; frame 0: all "))
        << what;
    EXPECT_TRUE(contains(what, "; frame 5: all ")) << what;
  }
}

/// Two cameras 0.3 m apart, frames 0-7 seen by both; camera 1 also sees frame 100 along one
/// board column, camera 0 frame 101 with 3 points.
ObservationSet rig_set(bool camera_1_degenerate_only) {
  std::mt19937_64 rng(7);
  ObservationSet set;
  add_views(set, 0, range(0, 8), rng);
  add_views(set, 1, range(0, 8), rng, camera_1_degenerate_only ? column_3 : nullptr, 0.3);
  if (camera_1_degenerate_only) return set;
  add_views(set, 1, {8}, rng, column_3, 0.3);
  add_views(set, 0, {9}, rng, three_points);
  for (Observation& o : set.observations)
    if (o.frame >= 8) o.frame += 92;
  return set;
}

TEST(DegenerateViews, RigSkipsEachNamedAndMatchesTheFitWithoutThem) {
  const ObservationSet set = rig_set(false);
  const RigResult r = calibrate_rig(set, RigOptions{});
  ASSERT_EQ(r.cameras.size(), 2u);
  ASSERT_EQ(r.cameras[0].views_skipped.size(), 1u);
  EXPECT_EQ(r.cameras[0].views_skipped[0].frame, 101);
  EXPECT_EQ(r.cameras[0].views_skipped[0].reason, "3 points, a homography needs >= 4");
  ASSERT_EQ(r.cameras[1].views_skipped.size(), 1u);
  EXPECT_EQ(r.cameras[1].views_skipped[0].frame, 100);
  EXPECT_TRUE(contains(r.cameras[1].views_skipped[0].reason, "on one board column (x = 0.15 m)"));
  const RigResult good = calibrate_rig(without_frames(set, 100), RigOptions{});
  for (size_t c = 0; c < 2; ++c)
    expect_same_parameters(r.cameras[c].intrinsics, good.cameras[c].intrinsics);
  EXPECT_NEAR((r.cameras[1].T_c_r.translation() - good.cameras[1].T_c_r.translation()).norm(), 0,
              1e-12);
  // Against the truth: the 0.3 m baseline within 5 of its sigma.
  EXPECT_LT(std::abs(r.cameras[1].baseline_m - 0.3), 5 * r.cameras[1].baseline_sigma_m);
}

/// The command's exit code, stdout and stderr.
struct CommandRun {
  int rc = 0;
  std::string out, err;
};

CommandRun run_intrinsic_on(const ObservationSet& set, const std::string& name) {
  calibapp::IntrinsicArgs args;
  args.observations = temp_path(name + ".csv");
  write_observations_csv(set, args.observations);
  args.output = temp_path(name + ".json");
  std::ostringstream out, err;
  const int rc = calibapp::run_intrinsic(args, out, err);
  return {rc, out.str(), err.str()};
}

CommandRun run_rig_on(const ObservationSet& set, const std::string& name,
                      const std::string& output) {
  calibapp::RigArgs args;
  args.observations = {temp_path(name + ".csv")};
  write_observations_csv(set, args.observations[0]);
  args.output = output;
  std::ostringstream out, err;
  const int rc = calibapp::run_rig(args, out, err);
  return {rc, out.str(), err.str()};
}

TEST(DegenerateViews, CommandsWarnPerViewCountThemAndNeverShowTheSolversLog) {
  const CommandRun i = run_intrinsic_on(intrinsic_set_with_degenerate_views(), "intrinsic");
  EXPECT_EQ(i.rc, 0) << i.err;
  EXPECT_TRUE(contains(i.out, "rejected as outliers, 5 views skipped\n")) << i.out;
  EXPECT_TRUE(contains(i.err,
                       "warning: camera 0 frame 100 skipped: all 7 points on one board column "
                       "(x = 0.15 m): no homography from collinear points\n"))
      << i.err;
  EXPECT_TRUE(contains(i.err,
                       "warning: camera 0 frame 103 skipped: 3 points, a homography "
                       "needs >= 4\n"))
      << i.err;

  const CommandRun r = run_rig_on(rig_set(false), "rig", temp_path("rig.json"));
  EXPECT_EQ(r.rc, 0) << r.err;
  EXPECT_TRUE(contains(r.out, "rejected as outliers, 2 views skipped\n")) << r.out;
  EXPECT_TRUE(contains(r.err, "warning: camera 1 frame 100 skipped: all ")) << r.err;
  EXPECT_TRUE(contains(r.err, "warning: camera 0 frame 101 skipped: 3 points")) << r.err;
  for (const std::string& text : {i.err, r.err}) {
    EXPECT_FALSE(contains(text, "ParameterBlock")) << text;
    EXPECT_FALSE(contains(text, "nan")) << text;
  }
}

TEST(DegenerateViews, RigCameraWithNoUsableViewIsExit2AndOverwritesNothing) {
  const std::string output = temp_path("rig_kept.json");
  std::ofstream(output) << "previous\n";
  const CommandRun r = run_rig_on(rig_set(true), "rig_no_view", output);
  EXPECT_EQ(r.rc, 2);
  EXPECT_TRUE(contains(r.err, ": camera 1: no usable view (all skipped; frame 0: all ")) << r.err;
  EXPECT_TRUE(contains(r.err,
                       "on one board column (x = 0.15 m): no homography from collinear "
                       "points; frame 1: "))
      << r.err;
  EXPECT_FALSE(contains(r.err, "ParameterBlock")) << r.err;
  std::ifstream in(output);
  std::string kept;
  std::getline(in, kept);
  EXPECT_EQ(kept, "previous");
}

}  // namespace
}  // namespace storetrack::calib
