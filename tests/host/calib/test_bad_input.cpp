// Bad input to storetrack-calib (issue 9, "Done when"): each refusal names the file, image or
// field the metrologist has to fix. The cases the other test files already cover, by test:
//   unreadable image         ChessboardImages.UnreadableAndBoardlessImagesRejectedWithReason,
//                            ChessboardImages.DetectCommandReportsAndRefusesEmptyResult
//   board not found          ChessboardImages.UnreadableAndBoardlessImagesRejectedWithReason
//                            (the rejected image's path and "board not found (10x7 ...)")
//   too few usable marks     WorldRegistration.Refusals (the observation file and point_id),
//                            WorldRegistration.SurveyWithTooFewMarksNamesTheSurvey
// Here the program-level refusals (the observation files named, not only the camera) and the
// inconsistent board geometry (square size), which no check caught before.
#include <gtest/gtest.h>

#include <filesystem>
#include <random>
#include <sstream>

#include "calib_cli.hpp"
#include "calib_commands.hpp"
#include "storetrack/calib/observations.hpp"
#include "synthetic_board.hpp"

namespace storetrack::calib {
namespace {

std::string temp_path(const std::string& name) {
  return (std::filesystem::temp_directory_path() / ("storetrack_bad_input_" + name)).string();
}

/// Board views of `camera` for `frames`: the camera `offset_m` to the right of camera 0's place.
ObservationSet board_views(int camera, const std::vector<int>& frames, std::mt19937_64& rng,
                           bool parallel = false, double square_m = test::kSquare,
                           double offset_m = 0) {
  const camera::CameraModel model(test::truth_camera());
  std::normal_distribution<double> noise(0, 0.2);
  test::BoardGrid grid;
  grid.square_m = square_m;
  geometry::Transform T_c_c0 = geometry::Transform::Identity();
  T_c_c0.translation() = geometry::Vec3(-offset_m, 0, 0);
  ObservationSet set;
  set.image_sizes[camera] = {1920, 1024};
  for (int i : frames)
    test::add_board_view(model, T_c_c0 * test::board_pose(i, parallel, grid), camera, i, noise, rng,
                         set, grid);
  return set;
}

std::string write_csv(const ObservationSet& set, const std::string& name) {
  const std::string path = temp_path(name);
  write_observations_csv(set, path);
  return path;
}

std::vector<int> range(int first, int end) {
  std::vector<int> out;
  for (int i = first; i < end; ++i)
    out.push_back(i);
  return out;
}

/// run_intrinsic's exit code and error text.
std::pair<int, std::string> intrinsic_error(const std::string& observations) {
  calibapp::IntrinsicArgs args;
  args.observations = observations;
  args.output = temp_path("intrinsic.json");
  std::ostringstream out, err;
  const int rc = calibapp::run_intrinsic(args, out, err);
  return {rc, err.str()};
}

std::pair<int, std::string> rig_error(const std::vector<std::string>& observations) {
  calibapp::RigArgs args;
  args.observations = observations;
  args.output = temp_path("rig.json");
  std::ostringstream out, err;
  const int rc = calibapp::run_rig(args, out, err);
  return {rc, err.str()};
}

TEST(BadInput, TooFewViewsNamesTheFileAndCamera) {
  std::mt19937_64 rng(1);
  const std::string path = write_csv(board_views(0, {0, 1}, rng), "two_views.csv");
  const auto [rc, err] = intrinsic_error(path);
  EXPECT_EQ(rc, 2);
  EXPECT_NE(err.find("error: " + path + ": camera 0: too few usable views: 2 board poses"),
            std::string::npos)
      << err;
}

TEST(BadInput, ParallelBoardsNameTheFileAndCamera) {
  std::mt19937_64 rng(2);
  const std::string path = write_csv(board_views(0, range(0, 12), rng, true), "parallel.csv");
  const auto [rc, err] = intrinsic_error(path);
  EXPECT_EQ(rc, 2);
  EXPECT_NE(err.find("error: " + path + ": camera 0: degenerate views"), std::string::npos) << err;
  EXPECT_NE(err.find("parallel"), std::string::npos) << err;
}

TEST(BadInput, CameraNeverSeenWithAnotherNamesTheFilesAndCamera) {
  std::mt19937_64 rng(3);
  const std::string a = write_csv(board_views(0, range(0, 6), rng), "camera0.csv");
  const std::string b =
      write_csv(board_views(1, range(6, 12), rng, false, test::kSquare, 0.3), "camera1.csv");
  const auto [rc, err] = rig_error({a, b});
  EXPECT_EQ(rc, 2);
  EXPECT_NE(err.find("error: " + a + ", " + b +
                     ": camera 1: never seen together with the reference camera 0"),
            std::string::npos)
      << err;
}

// Two observation files of one rig whose boards disagree: camera 1's corners were detected with
// --square 0.048 instead of 0.05. Merged, the board would be two sizes at once and the baseline
// scaled by whichever the fit favoured; the program refuses, naming both files, the column and
// the scale between them.
TEST(BadInput, InconsistentSquareSizeAcrossFilesNamesBothFiles) {
  std::mt19937_64 rng(4);
  const std::string a = write_csv(board_views(0, range(0, 8), rng), "square_050.csv");
  const std::string b =
      write_csv(board_views(1, range(0, 8), rng, false, 0.048, 0.3), "square_048.csv");
  const auto [rc, err] = rig_error({a, b});
  EXPECT_EQ(rc, 2);
  EXPECT_NE(err.find("error: " + b +
                     ": board_x_m: point 1 at (0.048, 0, 0) m, but (0.05, 0, 0) "
                     "m in " +
                     a + " (scale 0.96: a different square size?)"),
            std::string::npos)
      << err;
}

// One file whose rows disagree on a point's board position (two detections with different
// --square appended to one file): the later line is named with the line it contradicts.
TEST(BadInput, InconsistentSquareSizeWithinAFileNamesBothLines) {
  const std::string text =
      "camera,frame,point_id,board_x_m,board_y_m,board_z_m,image_x_px,image_y_px\n"
      "0,0,1,0.05,0,0,100,100\n"
      "0,1,1,0.048,0,0,120,100\n";
  try {
    parse_observations_csv(text, "mixed.csv");
    ADD_FAILURE() << "accepted";
  } catch (const ObservationFileError& e) {
    EXPECT_EQ(std::string(e.what()),
              "mixed.csv:3: board_x_m: point 1 at (0.048, 0, 0) m, but (0.05, 0, 0) m on line 2 "
              "(scale 0.96: a different square size?); one board per calibration, every point "
              "at one board position");
  }
  // Within the tolerance (1 um, printing noise of another tool) the rows agree.
  EXPECT_NO_THROW(parse_observations_csv(
      "camera,frame,point_id,board_x_m,board_y_m,board_z_m,image_x_px,image_y_px\n"
      "0,0,1,0.05,0,0,100,100\n0,1,1,0.0500004,0,0,120,100\n",
      "close.csv"));
}

// Board deflection (docs/calibration.md, "Board deflection"): a board point far off its plane
// and `on` on a board that cannot determine the bowl are refused by name, nothing written; an
// unknown --board-deflection value is a bad argument.
TEST(BadInput, BoardOffItsPlaneOrAnUndeterminedBowlRefusedByName) {
  std::mt19937_64 rng(5);
  ObservationSet set = board_views(0, range(0, 8), rng);
  for (Observation& o : set.observations)  // one board: point 3 off the plane in every frame
    if (o.point_id == 3) o.p_board.z() = 0.1;
  const std::string far_off = write_csv(set, "far_off_plane.csv");
  std::filesystem::remove(temp_path("intrinsic.json"));
  auto [rc, err] = intrinsic_error(far_off);
  EXPECT_EQ(rc, 2);
  EXPECT_NE(err.find("error: " + far_off +
                     ": camera 0: frame 0 point 3: board z = 0.1 m, more than 10 % of the "
                     "board's larger side (0.45 m)"),
            std::string::npos)
      << err;
  EXPECT_FALSE(std::filesystem::exists(temp_path("intrinsic.json")));

  test::BoardGrid two_columns;
  two_columns.cols = 2;
  ObservationSet narrow;
  narrow.image_sizes[0] = {1920, 1024};
  std::normal_distribution<double> noise(0, 0.2);
  const camera::CameraModel model(test::truth_camera());
  for (int i = 0; i < 8; ++i)
    test::add_board_view(model, test::board_pose(i, false, two_columns), 0, i, noise, rng, narrow,
                         two_columns);
  calibapp::IntrinsicArgs args;
  args.observations = write_csv(narrow, "two_columns.csv");
  args.output = temp_path("intrinsic.json");
  args.options.board_deflection = BoardDeflection::on;
  std::ostringstream out, err_text;
  EXPECT_EQ(calibapp::run_intrinsic(args, out, err_text), 2);
  EXPECT_NE(err_text.str().find("error: " + args.observations +
                                ": camera 0: the board deflection cannot be fitted: the board "
                                "has 2 distinct x and 7 distinct y coordinates"),
            std::string::npos)
      << err_text.str();
  EXPECT_FALSE(std::filesystem::exists(args.output));

  std::vector<std::string> argv_text = {
      "storetrack-calib", "intrinsic",          args.observations, "-o",
      args.output,        "--board-deflection", "sometimes"};
  std::vector<char*> argv;
  for (std::string& a : argv_text)
    argv.push_back(a.data());
  calibapp::CalibCommand command;
  EXPECT_EQ(calibapp::parse_calib_command(static_cast<int>(argv.size()), argv.data(), command), 2);
  argv_text[6] = "off";
  argv.clear();
  for (std::string& a : argv_text)
    argv.push_back(a.data());
  ASSERT_EQ(calibapp::parse_calib_command(static_cast<int>(argv.size()), argv.data(), command), -1);
  EXPECT_EQ(command.intrinsic.options.board_deflection, BoardDeflection::off);
}

}  // namespace
}  // namespace storetrack::calib
