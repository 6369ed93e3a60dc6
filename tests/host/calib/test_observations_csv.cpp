// Observation CSV: round trip bit for bit, and every malformed input refused with file, line
// and field named.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "storetrack/calib/observations.hpp"

namespace storetrack::calib {
namespace {

const char* const kHeader =
    "camera,frame,point_id,board_x_m,board_y_m,board_z_m,image_x_px,image_y_px,sigma_px\n";

TEST(ObservationCsv, RoundTripIsExact) {
  ObservationSet set;
  set.image_sizes[3] = {1920, 1024};
  set.frame_sources[7] = "cam3/img 007.png";
  Observation a;
  a.camera = 3;
  a.frame = 7;
  a.point_id = 12;
  a.p_board = {0.1 / 3, 0.05, 0};
  a.pixel = {std::nextafter(812.25, 1e9), 1.0 / 7};
  a.sigma_px = 0.07;
  Observation b = a;
  b.point_id = 13;
  b.sigma_px.reset();
  set.observations = {a, b};

  const ObservationSet back = parse_observations_csv(format_observations_csv(set), "mem.csv");
  ASSERT_EQ(back.observations.size(), 2u);
  for (size_t i = 0; i < 2; ++i) {
    const Observation& x = set.observations[i];
    const Observation& y = back.observations[i];
    EXPECT_EQ(x.camera, y.camera);
    EXPECT_EQ(x.frame, y.frame);
    EXPECT_EQ(x.point_id, y.point_id);
    EXPECT_EQ(x.p_board, y.p_board);  // bit for bit
    EXPECT_EQ(x.pixel, y.pixel);
    EXPECT_EQ(x.sigma_px, y.sigma_px);
  }
  EXPECT_EQ(back.image_sizes.at(3).width, 1920);
  EXPECT_EQ(back.image_sizes.at(3).height, 1024);
  EXPECT_EQ(back.frame_sources.at(7), "cam3/img 007.png");
}

TEST(ObservationCsv, EightColumnsWithoutSigmaAccepted) {
  const auto set = parse_observations_csv(
      "camera,frame,point_id,board_x_m,board_y_m,board_z_m,image_x_px,image_y_px\n"
      "0,1,2,0.025,0,0,100.5,200.25\n",
      "x.csv");
  ASSERT_EQ(set.observations.size(), 1u);
  EXPECT_FALSE(set.observations[0].sigma_px);
  EXPECT_EQ(set.observations[0].pixel.y(), 200.25);
}

std::string error_of(const std::string& text) {
  try {
    parse_observations_csv(text, "obs.csv");
  } catch (const ObservationFileError& e) {
    return e.what();
  }
  return "(accepted)";
}

TEST(ObservationCsv, MalformedInputNamesFileLineAndField) {
  const std::string row = "0,1,2,0.025,0,0,100.5,200.25,0.1\n";
  EXPECT_EQ(error_of(std::string(kHeader) + row + "0,1,3,0.05,0,0,abc,200,\n"),
            "obs.csv:3: image_x_px: expected a number, got 'abc'");
  EXPECT_EQ(error_of(std::string(kHeader) + "# comment\n\n0,x1,2,0,0,0,1,2,\n"),
            "obs.csv:4: frame: expected an integer, got 'x1'");
  EXPECT_EQ(error_of(std::string(kHeader) + "0,1,2,0,0,0,1,2,-0.5\n"),
            "obs.csv:2: sigma_px: must be > 0");
  EXPECT_EQ(error_of(std::string(kHeader) + "0,1,2,0,0,0,1\n"),
            "obs.csv:2: row: expected 9 fields, got 7");
  EXPECT_EQ(error_of(std::string(kHeader) + "300,1,2,0,0,0,1,2,\n"),
            "obs.csv:2: camera: 300 out of range 0..255");
  EXPECT_EQ(error_of(std::string(kHeader) + "0,1,2,nan,0,0,1,2,\n"),
            "obs.csv:2: board_x_m: not finite");
  EXPECT_EQ(error_of(std::string(kHeader) + row + row),
            "obs.csv:3: point_id: camera 0 frame 1 point 2 already on line 2");
  EXPECT_EQ(error_of("camera,frame,point,board_x_m,board_y_m,board_z_m,image_x_px,image_y_px\n"),
            "obs.csv:1: header: column 3 must be 'point_id', got 'point'");
  EXPECT_EQ(error_of("# only a comment\n"), "obs.csv:1: header: no header line (empty file?)");
  EXPECT_EQ(error_of("# image_size,0,640\n" + std::string(kHeader)),
            "obs.csv:1: image_size: expected camera,width,height");
}

TEST(ObservationCsv, MissingFileNamed) {
  try {
    read_observations_csv("/nonexistent/obs.csv");
    FAIL() << "accepted";
  } catch (const ObservationFileError& e) {
    EXPECT_EQ(std::string(e.what()),
              "/nonexistent/obs.csv: cannot open (No such file or directory)");
  }
}

}  // namespace
}  // namespace storetrack::calib
