// `compare` inside the observed region (issue 28): two rig calibrations whose 5-coefficient
// Brown distortion was fitted on boards seen only in the image centre, from synthetic board
// views projected through the true rig with Gaussian noise (different noise per calibration).
// Without the region record their differences outside the centre are extrapolation; with it
// the outside pixels and points are marked, counted and warned about, and the inside
// differences pass the joint chi-square test against both stated covariances. Also the
// calibration file's observed_region section: round trip, and refusals naming the field.
#include <gtest/gtest.h>

#include <filesystem>
#include <iostream>
#include <random>
#include <sstream>

#include "calib_commands.hpp"
#include "compare_command.hpp"
#include "storetrack/calib/calibration_comparison.hpp"
#include "storetrack/calib/rig_calibration.hpp"
#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/uncertainty/statistics.hpp"
#include "synthetic_board.hpp"

namespace storetrack::calib {
namespace {

using geometry::Vec2;
using geometry::Vec3;

constexpr int kCameras = 2;

/// The central window where the boards are seen: exactly the calibration file's grid cells
/// 4..11 x 2..5 (16 x 8 cells of 120 x 128 px on 1920 x 1024).
bool in_centre(const Vec2& pixel) {
  const double x = pixel.x() + 0.5, y = pixel.y() + 0.5;
  return x >= 480 && x < 1440 && y >= 256 && y < 768;
}

/// Camera 1 0.35 m to the right of camera 0, turned 0.1 rad towards it.
geometry::Transform truth_T_c_r(int c) {
  if (c == 0) return geometry::Transform::Identity();
  return geometry::make_transform(Vec3(0, -0.10, 0), Vec3(0.35, 0, 0)).inverse();
}

/// T_r_b of frame i: 1.3-2.1 m away, between the cameras, tilted 20-40 degrees.
geometry::Transform board_pose(int i) {
  const double turn = 2.39996 * i;
  const double tilt = (20 + 20 * ((i * 7) % 11) / 10.0) * M_PI / 180;
  const Vec3 axis(std::cos(turn), std::sin(turn), 0);
  const geometry::Mat3 R = Eigen::AngleAxisd(tilt, axis).toRotationMatrix() *
                           Eigen::AngleAxisd(0.3 * i, Vec3::UnitZ()).toRotationMatrix();
  const double z = 1.3 + 0.8 * ((i * 5) % 9) / 8.0;
  const Vec3 centre_r(0.12 + 0.08 * z * std::cos(1.3 * i), 0.05 * z * std::sin(1.7 * i), z);
  const Vec3 centre_board(0.5 * (test::kCols - 1) * test::kSquare,
                          0.5 * (test::kRows - 1) * test::kSquare, 0);
  geometry::Transform T = geometry::Transform::Identity();
  T.linear() = R;
  T.translation() = centre_r - R * centre_board;
  return T;
}

/// Board corners of every frame in both cameras, only those in the central window.
ObservationSet centre_only_views(std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0, 0.1);
  ObservationSet all;
  for (int c = 0; c < kCameras; ++c) {
    all.image_sizes[c] = {1920, 1024};
    const camera::CameraModel model(test::truth_camera());
    for (int i = 0; i < 24; ++i)
      test::add_board_view(model, truth_T_c_r(c) * board_pose(i), c, i, noise, rng, all);
  }
  ObservationSet centre = all;
  std::erase_if(centre.observations, [](const Observation& o) { return !in_centre(o.pixel); });
  return centre;
}

/// The calibration file storetrack-calib rig writes for the centre-only views (regions recorded).
camera::RigCalibration centre_calibration(std::uint64_t seed) {
  const ObservationSet set = centre_only_views(seed);
  RigOptions options;
  // k1, k2, k3 free (k3 is the issue's large term: r^6, backed by the centre only). The rational
  // k4..k6 are not identifiable from the centre at all (a singular normal matrix, refused).
  const RigResult result = calibrate_rig(set, options);
  return camera::parse_rig_calibration(calibapp::rig_calibration_json(result, 0, options, &set),
                                       "centre_" + std::to_string(seed) + ".json");
}

CompareOptions options_for(const std::string& a, const std::string& b) {
  CompareOptions o;
  o.origin_a = a;
  o.origin_b = b;
  o.volume_points = {7, 7, 7};
  o.grid_columns = 32;
  o.grid_rows = 16;
  return o;
}

struct CentrePair {
  camera::RigCalibration a = centre_calibration(1), b = centre_calibration(2);
};
const CentrePair& centre_pair() {
  static const CentrePair pair;
  return pair;
}

TEST(CompareObservedRegion, TheRigFileRecordsWhereTheFitHadPoints) {
  const camera::RigCalibration& a = centre_pair().a;
  for (const auto& cam : a.cameras) {
    ASSERT_TRUE(a.observed_regions.contains(cam.camera_id)) << "camera " << cam.camera_id;
    const camera::ObservedRegion& region = a.observed_regions.at(cam.camera_id);
    for (int r = 0; r < region.rows; ++r)
      for (int c = 0; c < region.columns; ++c) {
        const int n = region.counts[static_cast<size_t>(r * region.columns + c)];
        if (c < 4 || c > 11 || r < 2 || r > 5) {
          EXPECT_EQ(n, 0) << "camera " << cam.camera_id << " cell " << c << "," << r;
        }
      }
  }
}

TEST(CompareObservedRegion, WithoutTheRecordTheExtrapolationIsReportedAsADifference) {
  camera::RigCalibration a = centre_pair().a, b = centre_pair().b;
  a.observed_regions.clear();  // as a file written before issue 28
  b.observed_regions.clear();
  const ComparisonResult r = compare_calibrations(a, b, options_for("a.json", "b.json"));
  double max_px = 0;
  for (const auto& c : r.cameras) {
    EXPECT_EQ(c.outside_pixels, 0);
    max_px = std::max(max_px, c.fitted.max);
  }
  std::cout << "without observed regions: max projection difference " << max_px
            << " px, triangulated max " << r.difference_m.max * 1e3 << " mm, joint chi2 "
            << r.joint_chi2 << " for " << r.joint_dof << " dof\n";
  EXPECT_GT(max_px, 5.0);  // the edge of the image: two extrapolations of k1..k6 disagree
  // Every camera of both files is named as unchecked.
  ASSERT_EQ(r.warnings.size(), 2u * kCameras);
  for (const std::string& w : r.warnings)
    EXPECT_NE(w.find("has no observed_region record: the comparison cannot check"),
              std::string::npos)
        << w;
}

TEST(CompareObservedRegion, InsideTheRegionTheDifferencesAreWithinTheirUncertainty) {
  const CompareOptions options = options_for("a.json", "b.json");
  const ComparisonResult r = compare_calibrations(centre_pair().a, centre_pair().b, options);
  int warned_cameras = 0;
  for (const auto& c : r.cameras) {
    EXPECT_GT(c.outside_pixels, 0);
    EXPECT_GT(c.fitted.count, 0);
    for (size_t i = 0; i < c.pixels.size(); ++i) {
      if (c.inside[i]) {
        EXPECT_TRUE(in_centre(c.pixels[i])) << c.pixels[i].transpose();
      }
    }
    std::cout << "camera " << c.camera_id << ": inside max " << c.fitted.max << " px, outside max "
              << c.fitted_outside.max << " px (" << c.outside_pixels << " pixels)\n";
    for (const std::string& w : r.warnings)
      if (w.starts_with("camera " + std::to_string(c.camera_id) + ": ") &&
          w.find("outside the observed region") != std::string::npos)
        ++warned_cameras;
  }
  EXPECT_EQ(warned_cameras, kCameras);
  EXPECT_GT(r.valid_points, 10);
  EXPECT_GT(r.outside_points, 0);
  for (const auto& p : r.points)
    if (p.valid) {
      EXPECT_GE(p.cameras_inside, 2);
    }
  // Consistent sets: the joint chi-square of the inside differences is one draw of
  // chi-square(dof); two-sided band at total false alarm 1e-3.
  using uncertainty::DegreesOfFreedom;
  using uncertainty::Probability;
  const double lo =
      uncertainty::chi_square_quantile(Probability(5e-4), DegreesOfFreedom(r.joint_dof));
  const double hi =
      uncertainty::chi_square_quantile(Probability(1 - 5e-4), DegreesOfFreedom(r.joint_dof));
  std::cout << "inside: " << r.valid_points << " points, max |d| " << r.difference_m.max * 1e3
            << " mm, joint chi2 " << r.joint_chi2 << " for " << r.joint_dof << " dof (band " << lo
            << " .. " << hi << ")\n";
  EXPECT_GT(r.joint_dof, 0);
  EXPECT_GE(r.joint_chi2, lo);
  EXPECT_LE(r.joint_chi2, hi);
  // The verdict is compare's own test (false alarm options.false_alarm, 0.01) on this ONE draw: a
  // correct pair is called inconsistent 1 % of the time (the clang tree's solver path drew
  // chi2 30.9 for 10 dof, p = 0.0006, inside the band above), so what is checked is that the
  // verdict follows from the statistic, not that this draw passed a 1 % test.
  EXPECT_EQ(r.consistent, r.joint_p_value >= options.false_alarm) << r.verdict;
  std::cout << "verdict: " << (r.consistent ? "consistent" : "inconsistent")
            << " (p = " << r.joint_p_value << ")\n";
}

TEST(CompareObservedRegion, ObservedRegionRoundTripsAndOlderFilesStayReadable) {
  const camera::RigCalibration& a = centre_pair().a;
  const camera::RigCalibration back =
      camera::parse_rig_calibration(camera::format_rig_calibration(a), "back.json");
  ASSERT_EQ(back.observed_regions.size(), a.observed_regions.size());
  for (const auto& [id, region] : a.observed_regions)
    EXPECT_EQ(back.observed_regions.at(id).counts, region.counts);
  camera::RigCalibration old = a;
  old.observed_regions.clear();
  EXPECT_TRUE(camera::parse_rig_calibration(camera::format_rig_calibration(old), "old.json")
                  .observed_regions.empty());
}

/// The text of `rig` with camera 0's observed_region replaced by `region`.
std::string with_region(const camera::RigCalibration& rig, const std::string& region) {
  std::string text = camera::format_rig_calibration(rig);
  const size_t at = text.find("\"observed_region\"");
  const size_t end = text.find('}', at);
  return text.substr(0, at) + "\"observed_region\": " + region + text.substr(end + 1);
}

TEST(CompareObservedRegion, BadObservedRegionIsRefusedNamingTheField) {
  const camera::RigCalibration& a = centre_pair().a;
  const auto message = [&](const std::string& region) {
    try {
      camera::parse_rig_calibration(with_region(a, region), "bad.json");
    } catch (const camera::CalibrationFileError& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  EXPECT_NE(message(R"({"columns": 2, "rows": 1, "counts": [[1, 2, 3]]})")
                .find("bad.json: cameras[0].observed_region.counts[0]"),
            std::string::npos);
  EXPECT_NE(message(R"({"columns": 1, "rows": 1, "counts": [[-1]]})")
                .find("cameras[0].observed_region.counts[0][0]"),
            std::string::npos);
  EXPECT_NE(message(R"({"columns": 1, "rows": 1, "count": [[1]]})").find("observed_region"),
            std::string::npos);
}

TEST(CompareObservedRegion, TheCommandPrintsTheWarnings) {
  const std::string dir = ::testing::TempDir() + "/observed_region_cli";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  camera::write_rig_calibration(centre_pair().a, dir + "/a.json");
  camera::RigCalibration b = centre_pair().b;
  b.observed_regions.clear();
  camera::write_rig_calibration(b, dir + "/b.json");
  calibapp::CompareArgs args;
  args.a = dir + "/a.json";
  args.b = dir + "/b.json";
  args.volume.points_per_axis = 5;
  args.output = dir + "/compare.json";
  std::ostringstream out, err;
  EXPECT_EQ(calibapp::run_compare(args, out, err), 0) << err.str();
  EXPECT_NE(err.str().find("warning: " + args.b + ": camera 0 has no observed_region record"),
            std::string::npos)
      << err.str();
  EXPECT_NE(err.str().find("lie outside the observed region of " + args.a), std::string::npos)
      << err.str();
  EXPECT_NE(out.str().find("grid pixels outside the observed region"), std::string::npos)
      << out.str();
}

}  // namespace
}  // namespace storetrack::calib
