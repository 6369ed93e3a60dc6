// Real photographs: OpenCV's 9x6 stereo chessboard set (tests/data/opencv_stereo_chessboard_9x6,
// Apache-2.0, SOURCE.txt). Detection + intrinsic calibration of the 13 left images must reproduce
// OpenCV's published calibration (reference/left_intrinsics.yml; tolerances from REFERENCE.md),
// the program's calibration file must read back through common/camera, and unusable images
// must be rejected with their reason.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "calib_commands.hpp"
#include "storetrack/calib/chessboard_detection.hpp"
#include "storetrack/calib/intrinsic_calibration.hpp"
#include "storetrack/camera/calibration_file.hpp"

namespace storetrack::calib {
namespace {

const std::string kSet = std::string(STORETRACK_TEST_DATA_DIR) + "/opencv_stereo_chessboard_9x6";

std::vector<std::string> left_images() {
  std::vector<std::string> paths;
  for (int i : {1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14}) {
    char name[32];
    std::snprintf(name, sizeof name, "/images/left%02d.jpg", i);
    paths.push_back(kSet + name);
  }
  return paths;
}

// reference/left_intrinsics.yml (samples/cpp/calibration, flags = CALIB_FIX_ASPECT_RATIO).
constexpr double kPublishedF = 535.91573396163199;
constexpr double kPublishedCx = 342.28315473308373, kPublishedCy = 235.57082909788173;
constexpr double kPublishedRms = 0.39259098975581364;

TEST(ChessboardImages, LeftCameraReproducesOpenCvPublishedIntrinsics) {
  const DetectionResult detected = detect_chessboards(left_images(), {9, 6, 0.025}, 0);
  ASSERT_EQ(detected.images_used, 13);
  EXPECT_TRUE(detected.rejected.empty());
  ASSERT_EQ(detected.set.observations.size(), 13u * 54u);
  EXPECT_EQ(detected.set.image_sizes.at(0).width, 640);

  IntrinsicOptions options;
  options.fix_aspect_ratio = true;  // as the published run (flags = 2, aspect ratio 1)
  options.outlier_false_alarm = 0;  // cv::calibrateCamera keeps every point
  options.board_deflection = BoardDeflection::off;  // cv::calibrateCamera's board is flat
  const IntrinsicResult r = calibrate_intrinsics(detected.set, 0, options);
  std::printf("fx %.3f fy %.3f cx %.3f cy %.3f RMS %.4f px (published %.3f, %.4f)\n",
              r.intrinsics.fx, r.intrinsics.fy, r.intrinsics.cx, r.intrinsics.cy, r.rms_px,
              kPublishedF, kPublishedRms);
  EXPECT_NEAR(r.intrinsics.fx, kPublishedF, 1.5);
  EXPECT_EQ(r.intrinsics.fx, r.intrinsics.fy);
  EXPECT_NEAR(r.intrinsics.cx, kPublishedCx, 1.5);
  EXPECT_NEAR(r.intrinsics.cy, kPublishedCy, 1.5);
  EXPECT_NEAR(r.rms_px, kPublishedRms, 0.03);
  EXPECT_EQ(r.points_rejected, 0);
  // Tied aspect ratio: fx and fy are one parameter, so fully correlated in the covariance.
  EXPECT_NEAR(r.covariance(0, 1), r.covariance(0, 0), 1e-9 * r.covariance(0, 0));
  EXPECT_EQ(r.covariance(4, 4), 0);    // skew fixed
  EXPECT_EQ(r.covariance(10, 10), 0);  // k4 fixed

  // The program's file is a rig calibration file that common/camera reads back.
  const std::string text = calibapp::intrinsic_calibration_json(r, 0, 0, options);
  const camera::RigCalibration rig = camera::parse_rig_calibration(text, "calib.json");
  ASSERT_EQ(rig.cameras.size(), 1u);
  EXPECT_EQ(camera::pack(rig.cameras[0].model.intrinsics()), camera::pack(r.intrinsics));
  EXPECT_EQ(rig.cameras[0].intrinsic_covariance, r.covariance);

  // With the board's bowl fitted (the default): a nested model, so the RMS cannot rise.
  options.board_deflection = BoardDeflection::automatic;
  const IntrinsicResult bowed = calibrate_intrinsics(detected.set, 0, options);
  ASSERT_TRUE(bowed.board_deflection.fitted) << bowed.board_deflection.reason;
  const BoardDeflectionResult& d = bowed.board_deflection;
  std::printf(
      "board deflection fitted: c_x %.3f +- %.3f mm, c_y %.3f +- %.3f mm; fx %.3f; RMS "
      "%.4f px (flat %.4f)\n",
      1e3 * d.c_m.x(), 1e3 * std::sqrt(d.covariance(0, 0)), 1e3 * d.c_m.y(),
      1e3 * std::sqrt(d.covariance(1, 1)), bowed.intrinsics.fx, bowed.rms_px, r.rms_px);
  EXPECT_LE(bowed.rms_px, r.rms_px + 1e-9);
}

TEST(ChessboardImages, UnreadableAndBoardlessImagesRejectedWithReason) {
  const std::string missing = kSet + "/images/left10.jpg";  // there is no left10 upstream
  const std::string not_an_image = kSet + "/SOURCE.txt";
  const DetectionResult r = detect_chessboards({missing, not_an_image}, {9, 6, 0.025}, 0);
  ASSERT_EQ(r.rejected.size(), 2u);
  EXPECT_EQ(r.rejected[0].path, missing);
  EXPECT_NE(r.rejected[0].reason.find("unreadable"), std::string::npos);
  EXPECT_NE(r.rejected[1].reason.find("unreadable"), std::string::npos);
  EXPECT_EQ(r.images_used, 0);

  // A 9x6 board asked for as 10x7: not found, and said so.
  const DetectionResult wrong = detect_chessboards({left_images()[0]}, {10, 7, 0.025}, 0);
  ASSERT_EQ(wrong.rejected.size(), 1u);
  EXPECT_EQ(wrong.rejected[0].reason.rfind("board not found (10x7 inner corners", 0), 0u)
      << wrong.rejected[0].reason;
}

TEST(ChessboardImages, DetectCommandReportsAndRefusesEmptyResult) {
  calibapp::DetectArgs args;
  args.images = {kSet + "/images/left10.jpg"};
  args.output = (std::filesystem::temp_directory_path() / "storetrack_calib_none.csv").string();
  std::filesystem::remove(args.output);
  std::ostringstream out, err;
  EXPECT_EQ(calibapp::run_detect(args, out, err), 2);
  EXPECT_NE(err.str().find("rejected " + args.images[0] + ": unreadable"), std::string::npos);
  EXPECT_FALSE(std::filesystem::exists(args.output));
}

TEST(ChessboardImages, ProgramDetectsAndCalibratesEndToEnd) {
  const auto dir = std::filesystem::temp_directory_path() / "storetrack_calib_e2e";
  std::filesystem::create_directories(dir);
  calibapp::DetectArgs detect;
  detect.images = left_images();
  detect.output = (dir / "obs.csv").string();
  std::ostringstream out, err;
  ASSERT_EQ(calibapp::run_detect(detect, out, err), 0) << err.str();
  EXPECT_NE(out.str().find("13 of 13 images used, 0 rejected, 702 corners"), std::string::npos)
      << out.str();

  calibapp::IntrinsicArgs intrinsic;
  intrinsic.observations = detect.output;
  intrinsic.options.fix_aspect_ratio = true;
  intrinsic.output = (dir / "calib.json").string();
  intrinsic.residuals_csv = (dir / "residuals.csv").string();
  ASSERT_EQ(calibapp::run_intrinsic(intrinsic, out, err), 0) << err.str();
  // Default outlier gate: the first corner column of left02.jpg (2-6 px off) goes.
  EXPECT_NE(out.str().find("rejected as outliers"), std::string::npos);
  const camera::RigCalibration rig = camera::read_rig_calibration(intrinsic.output);
  ASSERT_EQ(rig.cameras.size(), 1u);
  EXPECT_EQ(rig.cameras[0].model.intrinsics().width, 640);
  EXPECT_GT(rig.cameras[0].intrinsic_covariance(0, 0), 0);

  // Bad input: exit 2, the message names the file, line and field.
  std::ofstream(dir / "bad.csv") << "camera,frame,point_id,board_x_m,board_y_m,board_z_m,"
                                    "image_x_px,image_y_px\n0,0,0,0,0,0,1.5,oops\n";
  intrinsic.observations = (dir / "bad.csv").string();
  std::ostringstream err2;
  EXPECT_EQ(calibapp::run_intrinsic(intrinsic, out, err2), 2);
  EXPECT_NE(err2.str().find("bad.csv:2: image_y_px: expected a number, got 'oops'"),
            std::string::npos)
      << err2.str();
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace storetrack::calib
