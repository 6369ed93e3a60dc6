// Rig calibration file: write/read round trip is exact, malformed files give a
// CalibrationFileError naming the file, the JSON path and the reason.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>

#include <nlohmann/json.hpp>

#include "storetrack/camera/calibration_file.hpp"

namespace storetrack::camera {
namespace {

using nlohmann::json;

/// A random symmetric positive-definite n x n covariance with standard deviations ~scale.
template <int N>
Eigen::Matrix<double, N, N> random_covariance(std::mt19937_64& rng, double scale) {
  std::normal_distribution<double> g(0, 1);
  Eigen::Matrix<double, N, N> a;
  for (int r = 0; r < N; ++r)
    for (int c = 0; c < N; ++c)
      a(r, c) = g(rng) * scale;
  return a * a.transpose() / N;
}

RigCalibration example_rig() {
  std::mt19937_64 rng(7);
  RigCalibration rig;
  for (int i = 0; i < 3; ++i) {
    CalibratedCamera cam;
    cam.camera_id = 2 * i + 1;
    cam.unit_id = i / 2;
    Intrinsics in;
    in.fx = 1450.123456789 + i;
    in.fy = 1449.987654321;
    in.cx = 961.25;
    in.cy = 510.75 - i;
    in.skew = 0.3;
    in.dist = {-0.2, 0.07, 1e-4, -2e-4, 0.01, i == 0 ? 0.0 : 0.02, 0.0, 1e-3};
    in.width = 1920;
    in.height = 1024;
    cam.model = CameraModel(in);
    cam.T_c_w = geometry::make_transform(geometry::Vec3(0.1, -0.4 + i, 0.02 * i),
                                         geometry::Vec3(-0.5 * i, 0.02, 3.5));
    cam.intrinsic_covariance = random_covariance<kNumIntrinsics>(rng, 1e-3);
    cam.extrinsic_covariance = random_covariance<6>(rng, 1e-4);
    cam.exposure_offset_ns = 1234.5 * i;
    cam.exposure_offset_sigma_ns = 50;
    rig.cameras.push_back(cam);
  }
  return rig;
}

/// example_rig() with a dense joint covariance (every camera correlated with every other, and
/// its intrinsics with its extrinsics): version 2.
RigCalibration example_joint_rig() {
  RigCalibration rig = example_rig();
  std::mt19937_64 rng(11);
  const int n = kJointBlockSize * static_cast<int>(rig.cameras.size());
  std::normal_distribution<double> g(0, 1);
  Eigen::MatrixXd a(n, n);
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c)
      a(r, c) = g(rng) * (r % kJointBlockSize < kNumIntrinsics ? 1e-2 : 1e-4);
  set_joint_covariance(rig, a * a.transpose() / n);
  return rig;
}

void expect_same_rig(const RigCalibration& a, const RigCalibration& b) {
  ASSERT_EQ(a.cameras.size(), b.cameras.size());
  EXPECT_EQ(a.joint_covariance, b.joint_covariance);
  for (size_t i = 0; i < a.cameras.size(); ++i) {
    const auto& ca = a.cameras[i];
    const auto& cb = b.cameras[i];
    EXPECT_EQ(ca.camera_id, cb.camera_id);
    EXPECT_EQ(ca.unit_id, cb.unit_id);
    EXPECT_EQ(pack(ca.model.intrinsics()), pack(cb.model.intrinsics()));
    EXPECT_EQ(ca.model.intrinsics().lens_model, cb.model.intrinsics().lens_model);
    EXPECT_EQ(ca.model.intrinsics().width, cb.model.intrinsics().width);
    EXPECT_EQ(ca.model.intrinsics().height, cb.model.intrinsics().height);
    EXPECT_EQ(ca.intrinsic_covariance, cb.intrinsic_covariance);
    EXPECT_EQ(ca.extrinsic_covariance, cb.extrinsic_covariance);
    // The rotation goes through a rotation vector: exact to rounding.
    EXPECT_LT((ca.T_c_w.matrix() - cb.T_c_w.matrix()).cwiseAbs().maxCoeff(), 1e-15);
    EXPECT_EQ(ca.exposure_offset_ns, cb.exposure_offset_ns);
    EXPECT_EQ(ca.exposure_offset_sigma_ns, cb.exposure_offset_sigma_ns);
  }
}

TEST(CalibrationFile, StringRoundTrip) {
  const RigCalibration rig = example_rig();
  const std::string text = format_rig_calibration(rig);
  expect_same_rig(rig, parse_rig_calibration(text, "memory"));
  // Reading what was written and writing it again changes nothing but rounding of the
  // rotation vector.
  expect_same_rig(rig, parse_rig_calibration(
                           format_rig_calibration(parse_rig_calibration(text, "memory")), "m2"));
}

TEST(CalibrationFile, FileRoundTripAndFind) {
  const RigCalibration rig = example_rig();
  const auto path = (std::filesystem::temp_directory_path() /
                     ("storetrack_calib_" + std::to_string(::getpid()) + ".json"))
                        .string();
  write_rig_calibration(rig, path);
  const RigCalibration back = read_rig_calibration(path);
  std::filesystem::remove(path);
  expect_same_rig(rig, back);
  ASSERT_NE(back.find(3), nullptr);
  EXPECT_EQ(back.find(3)->camera_id, 3);
  EXPECT_EQ(back.find(2), nullptr);
}

TEST(CalibrationFile, MissingFileNamesPath) {
  try {
    read_rig_calibration("/nonexistent/dir/calib.json");
    FAIL() << "no exception";
  } catch (const CalibrationFileError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/dir/calib.json"), std::string::npos);
  }
}

TEST(CalibrationFile, StandardDeviationShorthandAndOptionalFields) {
  json doc = json::parse(format_rig_calibration(example_rig()));
  json& cam = doc["cameras"][0];
  cam["intrinsic_covariance"] = {
      {"standard_deviations", {0.5, 0.5, 0.3, 0.3, 0, 1e-3, 1e-3, 1e-5, 1e-5, 1e-4, 0, 0, 0}}};
  cam["intrinsics"]["distortion"] = {-0.1, 0.01, 0, 0};  // 4 coefficients: k3..k6 = 0
  cam["intrinsics"].erase("skew");
  cam.erase("exposure_offset_ns");
  cam.erase("exposure_offset_sigma_ns");
  cam["comment"] = "hand-edited";
  const RigCalibration rig = parse_rig_calibration(doc.dump(), "memory");
  const auto& c = rig.cameras[0];
  EXPECT_DOUBLE_EQ(c.intrinsic_covariance(0, 0), 0.25);
  EXPECT_DOUBLE_EQ(c.intrinsic_covariance(5, 5), 1e-6);
  EXPECT_EQ(c.intrinsic_covariance(0, 1), 0);
  EXPECT_EQ(c.model.intrinsics().skew, 0);
  EXPECT_EQ(c.model.intrinsics().dist[4], 0);
  EXPECT_EQ(c.model.intrinsics().dist[0], -0.1);
  EXPECT_EQ(c.exposure_offset_ns, 0);
}

/// Applies `edit` to a valid document (of `base`) and expects an error whose message names the
/// origin, `path_fragment` and `reason_fragment`.
void expect_error(const std::function<void(json&)>& edit, const std::string& path_fragment,
                  const std::string& reason_fragment, const RigCalibration& base = example_rig()) {
  json doc = json::parse(format_rig_calibration(base));
  edit(doc);
  try {
    parse_rig_calibration(doc.dump(), "rig_under_test.json");
    ADD_FAILURE() << "no exception for " << path_fragment;
  } catch (const CalibrationFileError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("rig_under_test.json"), std::string::npos) << what;
    EXPECT_NE(what.find(path_fragment), std::string::npos) << what;
    EXPECT_NE(what.find(reason_fragment), std::string::npos) << what;
  }
}

TEST(CalibrationFile, MalformedFilesAreRejectedWithPathAndReason) {
  expect_error([](json& d) { d["format"] = "opencv"; }, "format",
               "expected \"storetrack-rig-calibration\"");
  expect_error([](json& d) { d["version"] = 3; }, "version", "unsupported version 3");
  expect_error([](json& d) { d.erase("cameras"); }, ": cameras", "missing");
  expect_error([](json& d) { d["cameras"] = json::array(); }, ": cameras",
               "expected an array of at least 1 elements, got 0");
  expect_error([](json& d) { d["camaras"] = 1; }, "camaras", "unknown key (did you mean cameras?)");
  expect_error([](json& d) { d["cameras"][1].erase("T_c_w"); }, "cameras[1].T_c_w", "missing");
  expect_error([](json& d) { d["cameras"][0]["intrinsics"]["fx"] = "1450"; },
               "cameras[0].intrinsics.fx", "expected a number in > 0");
  expect_error([](json& d) { d["cameras"][0]["intrinsics"]["fy"] = -3; },
               "cameras[0].intrinsics.fy", "expected a number in > 0, got -3");
  expect_error(
      [](json& d) {
        d["cameras"][2]["intrinsics"]["distortion"] = {0.1, 0.2, 0.0};
      },
      "cameras[2].intrinsics.distortion", "expected an array of 4 to 8 elements, got 3");
  expect_error(
      [](json& d) { d["cameras"][2]["intrinsics"]["distortion"] = {0.1, 0.2, 0, 0, 0, 0}; },
      "cameras[2].intrinsics.distortion", "4, 5 or 8");
  expect_error(
      [](json& d) {
        d["cameras"][0]["T_c_w"]["translation_m"] = {1, 2};
      },
      "cameras[0].T_c_w.translation_m", "expected an array of 3 elements, got 2");
  expect_error([](json& d) { d["cameras"][0]["T_c_w"]["rotation_vector_rad"][1] = nullptr; },
               "cameras[0].T_c_w.rotation_vector_rad[1]", "expected a number, got null");
  expect_error([](json& d) { d["cameras"][1]["camera_id"] = d["cameras"][0]["camera_id"]; },
               "cameras[1].camera_id", "duplicate camera_id");
  expect_error([](json& d) { d["cameras"][1]["camera_id"] = 300; }, "cameras[1].camera_id",
               "expected an integer in [0, 255], got 300");
  expect_error([](json& d) { d["cameras"][1]["camera_id"] = 1.5; }, "cameras[1].camera_id",
               "expected an integer in [0, 255], got 1.5");
  expect_error([](json& d) { d["cameras"][0]["image_size"]["width"] = 0; },
               "cameras[0].image_size.width", "expected an integer in [1, 65535], got 0");
  expect_error([](json& d) { d["cameras"][0]["extrinsic_covariance"][2][3] = 1.0; },
               "cameras[0].extrinsic_covariance[2][3]", "not symmetric");
  expect_error(
      [](json& d) {
        auto& c = d["cameras"][0]["extrinsic_covariance"];
        c[0][0] = -1.0;
      },
      "cameras[0].extrinsic_covariance[0][0]", "not positive semi-definite (negative variance)");
  expect_error([](json& d) { d["cameras"][0]["intrinsic_covariance"].erase(12); },
               "cameras[0].intrinsic_covariance", "13x13");
  expect_error([](json& d) { d["cameras"][0]["intrinsic_covariance"][4].erase(0); },
               "cameras[0].intrinsic_covariance[4]", "expected an array of 13 elements, got 12");
  expect_error(
      [](json& d) {
        d["cameras"][0]["extrinsic_covariance"] = {{"standard_deviations", {1, 1, 1, 1, -1, 1}}};
      },
      "cameras[0].extrinsic_covariance.standard_deviations[4]",
      "expected a number in >= 0, got -1");
  expect_error([](json& d) { d["cameras"][0]["exposure_offset_sigma_ns"] = -1; },
               "cameras[0].exposure_offset_sigma_ns", "expected a number in >= 0, got -1");
  expect_error([](json& d) { d["cameras"][0]["intrinsics"]["k1"] = 0.1; },
               "cameras[0].intrinsics.k1", "unknown key");
}

/// example_rig() with camera 3 a Kannala-Brandt fisheye (its unused entries 9..12 without
/// variance).
RigCalibration example_fisheye_rig() {
  RigCalibration rig = example_rig();
  CalibratedCamera& cam = rig.cameras[1];
  Intrinsics in = cam.model.intrinsics();
  in.lens_model = LensModel::kKannalaBrandt;
  in.fx = in.fy = 331.25;
  in.dist = {0.021, -0.008, 0.0031, -0.0007, 0, 0, 0, 0};
  cam.model = CameraModel(in);
  cam.intrinsic_covariance.bottomRows<4>().setZero();
  cam.intrinsic_covariance.rightCols<4>().setZero();
  return rig;
}

TEST(CalibrationFile, LensModelRoundTripAndDefault) {
  const RigCalibration rig = example_fisheye_rig();
  const std::string text = format_rig_calibration(rig);
  const json doc = json::parse(text);
  EXPECT_EQ(doc["cameras"][1]["intrinsics"]["model"], "kannala-brandt");
  EXPECT_EQ(doc["cameras"][1]["intrinsics"]["distortion"].size(), 4u);
  EXPECT_EQ(doc["cameras"][0]["intrinsics"]["model"], "rational-brown");
  expect_same_rig(rig, parse_rig_calibration(text, "memory"));
  // A file from before the field: the rational Brown model.
  json old = json::parse(format_rig_calibration(example_rig()));
  for (json& cam : old["cameras"])
    cam["intrinsics"].erase("model");
  expect_same_rig(example_rig(), parse_rig_calibration(old.dump(), "old"));
}

TEST(CalibrationFile, BadLensModelIsRejectedNamingTheField) {
  const RigCalibration fisheye = example_fisheye_rig();
  expect_error([](json& d) { d["cameras"][1]["intrinsics"]["model"] = "fisheye"; },
               "cameras[1].intrinsics.model", "unknown lens model \"fisheye\"", fisheye);
  expect_error([](json& d) { d["cameras"][1]["intrinsics"]["model"] = 2; },
               "cameras[1].intrinsics.model", "expected a string", fisheye);
  expect_error([](json& d) { d["cameras"][1]["intrinsics"]["distortion"].push_back(0.0); },
               "cameras[1].intrinsics.distortion",
               "expected 4 coefficients for the kannala-brandt model", fisheye);
  expect_error(
      [](json& d) {
        d["cameras"][0]["intrinsics"]["model"] = "kannala-brandt";  // 8 Brown coefficients
      },
      "cameras[0].intrinsics.distortion", "expected 4 coefficients for the kannala-brandt model");
}

TEST(CalibrationFile, Version2JointCovarianceRoundTrip) {
  const RigCalibration rig = example_joint_rig();
  ASSERT_TRUE(rig.has_cross_covariance());
  const std::string text = format_rig_calibration(rig);
  EXPECT_EQ(json::parse(text)["version"], 2);
  const RigCalibration back = parse_rig_calibration(text, "memory");
  expect_same_rig(rig, back);
  EXPECT_TRUE(back.has_cross_covariance());
  // The per-camera blocks are the joint's diagonal blocks.
  EXPECT_EQ(back.cameras[1].extrinsic_covariance,
            Eigen::MatrixXd(back.joint_covariance.block(kJointBlockSize + kNumIntrinsics,
                                                        kJointBlockSize + kNumIntrinsics, 6, 6)));
}

TEST(CalibrationFile, Version1IsReadWithZeroCrossCovariance) {
  const RigCalibration rig = example_rig();
  json doc = json::parse(format_rig_calibration(rig));
  doc["version"] = 1;
  const RigCalibration v1 = parse_rig_calibration(doc.dump(), "v1.json");
  expect_same_rig(rig, v1);
  EXPECT_EQ(v1.joint_covariance.size(), 0);
  EXPECT_FALSE(v1.has_cross_covariance());
  // The joint view of a version-1 rig: the cameras' blocks on the diagonal, zero elsewhere.
  const Eigen::MatrixXd joint = v1.full_joint_covariance();
  ASSERT_EQ(joint.rows(), 3 * kJointBlockSize);
  Eigen::MatrixXd expected = Eigen::MatrixXd::Zero(joint.rows(), joint.cols());
  for (int c = 0; c < 3; ++c) {
    const int at = c * kJointBlockSize;
    expected.block(at, at, kNumIntrinsics, kNumIntrinsics) =
        v1.cameras[static_cast<size_t>(c)].intrinsic_covariance;
    expected.block(at + kNumIntrinsics, at + kNumIntrinsics, 6, 6) =
        v1.cameras[static_cast<size_t>(c)].extrinsic_covariance;
  }
  EXPECT_EQ(joint, expected);
}

/// As expect_error, on the version-2 example.
void expect_joint_error(const std::function<void(json&)>& edit, const std::string& path_fragment,
                        const std::string& reason_fragment) {
  json doc = json::parse(format_rig_calibration(example_joint_rig()));
  edit(doc);
  try {
    parse_rig_calibration(doc.dump(), "rig_v2.json");
    ADD_FAILURE() << "no exception for " << path_fragment;
  } catch (const CalibrationFileError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("rig_v2.json: " + path_fragment), std::string::npos) << what;
    EXPECT_NE(what.find(reason_fragment), std::string::npos) << what;
  }
}

TEST(CalibrationFile, BadJointCovarianceIsRejectedNamingTheField) {
  // 3 cameras: 57 x 57.
  expect_joint_error([](json& d) { d["joint_covariance"]["matrix"].erase(56); },
                     "joint_covariance.matrix: ", "expected a 57x57");
  expect_joint_error([](json& d) { d["joint_covariance"]["matrix"][20].erase(3); },
                     "joint_covariance.matrix[20]: ", "expected an array of 57 elements, got 56");
  expect_joint_error(
      [](json& d) {
        auto& m = d["joint_covariance"]["matrix"];
        m[40][2] = m[40][2].get<double>() * 1.5 + 1e-6;
      },
      "joint_covariance.matrix[2][40]: ", "not symmetric");
  expect_joint_error(
      [](json& d) {
        // Correlation 1.5 between camera 0's fx and camera 2's tz: indefinite.
        auto& m = d["joint_covariance"]["matrix"];
        const double v = 1.5 * std::sqrt(m[0][0].get<double>() * m[56][56].get<double>());
        m[0][56] = v;
        m[56][0] = v;
      },
      "joint_covariance.matrix: ", "not positive semi-definite");
  expect_joint_error(
      [](json& d) {
        d["joint_covariance"]["camera_ids"] = {1, 5, 3};
      },
      "joint_covariance.camera_ids[1]: ", "expected camera_id 3");
  expect_joint_error(
      [](json& d) {
        d["joint_covariance"]["camera_ids"] = {1, 3};
      },
      "joint_covariance.camera_ids: ", "expected an array of 3 elements, got 2");
  expect_joint_error(
      [](json& d) {
        d["cameras"][1]["extrinsic_covariance"][0][0] =
            d["cameras"][1]["extrinsic_covariance"][0][0].get<double>() * 2;
      },
      "joint_covariance.matrix[32][32]: ", "differs from cameras[1].extrinsic_covariance[0][0]");
  expect_joint_error([](json& d) { d["version"] = 1; }, "joint_covariance: ", "needs version 2");
  expect_joint_error([](json& d) { d["joint_covariance"].erase("matrix"); },
                     "joint_covariance.matrix: ", "missing");
  expect_joint_error([](json& d) { d["joint_covariance"]["layout"] = 1; },
                     "joint_covariance.layout: ", "unknown key");
}

TEST(CalibrationFile, SyntaxErrorNamesFile) {
  try {
    parse_rig_calibration("{\"format\": \"storetrack-rig-calibration\", ", "broken.json");
    FAIL() << "no exception";
  } catch (const CalibrationFileError& e) {
    EXPECT_NE(std::string(e.what()).find("broken.json"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("broken.json: not valid JSON: "), std::string::npos);
  }
}

TEST(CalibrationFile, NonFiniteNumbersRejected) {
  // JSON has no NaN literal; a huge exponent overflows to inf in the parser.
  json doc = json::parse(format_rig_calibration(example_rig()));
  std::string text = doc.dump();
  const std::string key = "\"cx\":";
  const auto pos = text.find(key);
  ASSERT_NE(pos, std::string::npos);
  const auto end = text.find(',', pos);
  text.replace(pos + key.size(), end - pos - key.size(), "1e999");
  EXPECT_THROW(parse_rig_calibration(text, "inf.json"), CalibrationFileError);
}

}  // namespace
}  // namespace storetrack::camera
