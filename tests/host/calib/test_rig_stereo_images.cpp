// Real photographs: the rig calibration of OpenCV's 9x6 stereo chessboard set (13 left + 13
// right images, tests/data/opencv_stereo_chessboard_9x6, REFERENCE.md) must give the published
// baseline |T| = 0.0836 m within 0.5 mm, and RMS values bounded by REFERENCE.md's OpenCV runs
// on the same corners; the program's file must read back through common/camera.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "calib_cli.hpp"
#include "calib_commands.hpp"
#include "storetrack/calib/chessboard_detection.hpp"
#include "storetrack/calib/rig_calibration.hpp"
#include "storetrack/camera/calibration_file.hpp"

namespace storetrack::calib {
namespace {

const std::string kSet = std::string(STORETRACK_TEST_DATA_DIR) + "/opencv_stereo_chessboard_9x6";

std::vector<std::string> images(const char* side) {
  std::vector<std::string> paths;
  for (int i : {1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14}) {
    char name[48];
    std::snprintf(name, sizeof name, "/images/%s%02d.jpg", side, i);
    paths.push_back(kSet + name);
  }
  return paths;
}

// REFERENCE.md: published stereo baseline; OpenCV 4.6 on the same corners, flags = 0, 5 coeffs.
constexpr double kPublishedBaselineM = 0.0836;
constexpr double kOpenCvLeftRms = 0.40877, kOpenCvRightRms = 0.45872;  // each camera alone
constexpr double kOpenCvStereoFixedIntrinsicsRms = 0.44785;  // stereoCalibrate, intrinsics fixed
constexpr double kSolverSlackPx = 0.0005;  // rounding of REFERENCE.md's values, convergence

ObservationSet detect_stereo_set() {
  const ChessboardSpec board{9, 6, 0.025};
  ObservationSet set = detect_chessboards(images("left"), board, 0).set;
  const ObservationSet right = detect_chessboards(images("right"), board, 1).set;
  set.observations.insert(set.observations.end(), right.observations.begin(),
                          right.observations.end());
  set.image_sizes[1] = right.image_sizes.at(1);
  return set;
}

/// Detected once for both tests (26 images: a few seconds under the sanitizers).
const ObservationSet& stereo_set() {
  static const ObservationSet set = detect_stereo_set();
  return set;
}

TEST(RigStereoImages, BaselineAndRmsAsPublished) {
  const ObservationSet set = stereo_set();
  ASSERT_EQ(set.observations.size(), 2u * 13u * 54u);
  RigOptions options;                         // flags = 0 (OpenCV's default), 5 coefficients
  options.intrinsic.outlier_false_alarm = 0;  // OpenCV keeps every point
  options.intrinsic.board_deflection = BoardDeflection::off;  // OpenCV's board is flat
  const RigResult r = calibrate_rig(set, options);
  ASSERT_EQ(r.cameras.size(), 2u);
  const RigCameraResult& left = r.cameras[0];
  const RigCameraResult& right = r.cameras[1];
  std::printf("baseline %.5f +/- %.5f m (published %.4f), RMS left %.4f right %.4f all %.4f px\n",
              right.baseline_m, right.baseline_sigma_m, kPublishedBaselineM, left.rms_px,
              right.rms_px, r.rms_px);
  EXPECT_NEAR(right.baseline_m, kPublishedBaselineM, 0.0005);
  EXPECT_LT(right.T_c_r.translation().x(), 0);  // the right camera sits at +x of the left
  EXPECT_EQ(right.common_views_with_reference, 13);
  // Bounds, not tolerances: each camera's residual in the joint fit cannot be below its own
  // best fit (the joint fit is one of the single camera's feasible points), and the total not
  // above stereoCalibrate's with the intrinsics fixed at those fits (one of the rig's).
  EXPECT_GE(left.rms_px, kOpenCvLeftRms - kSolverSlackPx);
  EXPECT_GE(right.rms_px, kOpenCvRightRms - kSolverSlackPx);
  EXPECT_GE(left.rms_px, left.start_rms_px - 1e-9);
  EXPECT_GE(right.rms_px, right.start_rms_px - 1e-9);
  EXPECT_LE(r.rms_px, kOpenCvStereoFixedIntrinsicsRms + kSolverSlackPx);
  EXPECT_GT(right.baseline_sigma_m, 0);
  EXPECT_LT(right.baseline_sigma_m, 0.0005);
  EXPECT_EQ(r.joint_covariance.rows(), 2 * kRigBlockSize);
}

TEST(RigStereoImages, ProgramWritesARigCalibrationFile) {
  const auto dir = std::filesystem::temp_directory_path() / "storetrack_calib_rig_e2e";
  std::filesystem::create_directories(dir);
  const ObservationSet set = stereo_set();
  ObservationSet left = set, right = set;
  std::erase_if(left.observations, [](const Observation& o) { return o.camera != 0; });
  std::erase_if(right.observations, [](const Observation& o) { return o.camera != 1; });
  left.image_sizes.erase(1);
  right.image_sizes.erase(0);
  write_observations_csv(left, (dir / "left.csv").string());
  write_observations_csv(right, (dir / "right.csv").string());

  calibapp::RigArgs args;
  args.observations = {(dir / "left.csv").string(), (dir / "right.csv").string()};
  args.output = (dir / "rig.json").string();
  args.residuals_csv = (dir / "residuals.csv").string();
  std::ostringstream out, err;
  ASSERT_EQ(calibapp::run_rig(args, out, err), 0) << err.str();
  EXPECT_NE(out.str().find("baseline |T| = "), std::string::npos) << out.str();
  EXPECT_NE(out.str().find(" mm ("), std::string::npos) << out.str();
  const camera::RigCalibration rig = camera::read_rig_calibration(args.output);
  ASSERT_EQ(rig.cameras.size(), 2u);
  EXPECT_NEAR(rig.cameras[1].T_c_w.translation().norm(), kPublishedBaselineM, 0.0005);
  EXPECT_GT(rig.cameras[1].extrinsic_covariance(3, 3), 0);
  EXPECT_EQ(rig.cameras[0].extrinsic_covariance, geometry::Mat6::Zero());
  std::ifstream f(args.output);
  const nlohmann::json doc = nlohmann::json::parse(f);
  EXPECT_EQ(doc["version"], 2);
  // Version 2 carries the bundle adjustment's joint covariance, read back as written.
  const Eigen::MatrixXd& joint = rig.joint_covariance;
  ASSERT_EQ(joint.rows(), 2 * kRigBlockSize);
  // Cross-camera terms exist (shared board poses): fx of camera 0 with fx of camera 1.
  EXPECT_NE(joint(0, kRigBlockSize), 0.0);
  EXPECT_TRUE(rig.has_cross_covariance());
  EXPECT_EQ(joint(0, 0), rig.cameras[0].intrinsic_covariance(0, 0));

  // The command line reaches the same arguments.
  const std::string left_csv = (dir / "left.csv").string(),
                    right_csv = (dir / "right.csv").string();
  std::vector<std::string> argv_text = {"storetrack-calib",
                                        "rig",
                                        left_csv,
                                        right_csv,
                                        "-o",
                                        args.output,
                                        "--no-outlier-rejection",
                                        "--min-common-views",
                                        "5",
                                        "--image-size",
                                        "1=640x480"};
  std::vector<char*> argv;
  for (std::string& a : argv_text)
    argv.push_back(a.data());
  calibapp::CalibCommand command;
  ASSERT_EQ(calibapp::parse_calib_command(static_cast<int>(argv.size()), argv.data(), command), -1);
  EXPECT_EQ(command.kind, calibapp::CalibCommand::Kind::kRig);
  EXPECT_EQ(command.rig.observations, (std::vector<std::string>{left_csv, right_csv}));
  EXPECT_EQ(command.rig.options.intrinsic.outlier_false_alarm, 0);
  EXPECT_EQ(command.rig.options.min_common_views, 5);
  EXPECT_EQ(command.rig.image_sizes, std::vector<std::string>{"1=640x480"});

  // The same (camera, frame, point) in two files: refused, both files named.
  args.observations = {(dir / "left.csv").string(), (dir / "left.csv").string()};
  std::ostringstream err2;
  EXPECT_EQ(calibapp::run_rig(args, out, err2), 2);
  EXPECT_NE(err2.str().find("left.csv: camera 0 frame 0 point 0 is also in"), std::string::npos)
      << err2.str();
  // Only one camera: refused with exit 2.
  args.observations = {(dir / "left.csv").string()};
  std::ostringstream err3;
  EXPECT_EQ(calibapp::run_rig(args, out, err3), 2);
  EXPECT_NE(err3.str().find("at least 2 cameras"), std::string::npos) << err3.str();
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace storetrack::calib
