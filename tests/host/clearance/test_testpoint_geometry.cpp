// The store_separation scenario's clearance geometry as checked in (tools/testpoint's main job):
// the files are what testpoint_geometry.hpp writes; the captive store clears the pylon by the
// closed-form 5 cm and every aircraft part; the store survey's marks lie on the store's mesh.
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <iterator>
#include <limits>
#include <numbers>
#include <string>

#include "storetrack/clearance/clearance.hpp"
#include "storetrack/clearance/triangle_distance.hpp"
#include "storetrack/json/strict_reader.hpp"
#include "storetrack/json/text_file.hpp"
#include "storetrack/survey/survey.hpp"
#include "testpoint_geometry.hpp"

namespace storetrack::clearance {
namespace {

const std::string kDir = STORETRACK_SCENARIO_DIR "/store_separation_geometry";

std::string file_bytes(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

TEST(TestpointGeometry, CheckedInFilesAreTheGenerators) {
  const test::TestpointGeometry g = test::testpoint_geometry();
  EXPECT_EQ(file_bytes(kDir + "/store.stl"),
            test::stl_binary(g.store, "storetrack testpoint store"));
  EXPECT_EQ(file_bytes(kDir + "/pylon.stl"),
            test::stl_binary(g.pylon, "storetrack testpoint pylon"));
  EXPECT_EQ(file_bytes(kDir + "/wing_lower.stl"),
            test::stl_binary(g.wing_lower, "storetrack testpoint wing lower surface"));
  EXPECT_EQ(file_bytes(kDir + "/adjacent_store.stl"),
            test::stl_binary(g.adjacent_store, "storetrack testpoint adjacent store"));
}

TEST(TestpointGeometry, CaptiveStoreClearsThePylonByTheClosedForm) {
  ClearanceModel model = ClearanceModel::load(kDir + "/geometry.json");
  ASSERT_EQ(model.aircraft_parts(), 3u);
  // The scenario's captive pose T_p_s0: translation (0, 0, 0.2), no rotation.
  geometry::Transform T_p_s = geometry::Transform::Identity();
  T_p_s.translation() = geometry::Vec3(0, 0, 0.2);
  const auto parts = model.evaluate(T_p_s, geometry::Mat6::Identity() * 1e-8);
  EXPECT_EQ(parts[0].part, "pylon");
  // The top line's vertices (float32 in the STL) against the pylon's lower face at z = 0.
  EXPECT_NEAR(parts[0].distance_m, test::kTestpointCaptiveClearance_m, 1e-7);
  EXPECT_FALSE(parts[0].penetration);
  // The wing 0.5 m above the pylon's face, the adjacent store 1.1 m inboard (fins reach
  // 2.1 r sin 45 = 0.223 m sideways from each axis): both far, neither touched.
  EXPECT_NEAR(parts[1].distance_m, 0.2 + 0.5 - 0.223, 0.01);  // an upper fin's tip is nearest
  EXPECT_GT(parts[2].distance_m, 1.1 - 2 * 0.223 - 0.01);
  for (const PartClearance& p : parts)
    EXPECT_FALSE(p.penetration) << p.part;
}

TEST(TestpointGeometry, StoreSurveyMarksLieOnTheStoreMesh) {
  const std::string file = STORETRACK_SCENARIO_DIR "/store_separation.json";
  const jsonfile::Document doc = jsonfile::Document::parse(jsonfile::read_text_file(file), file);
  const survey::RigidBodySurvey store = survey::read_survey(doc.root().object().at("store_survey"));
  const TriangleMesh mesh = test::testpoint_geometry().store;
  ASSERT_EQ(store.marks.size(), 16u);
  for (const auto& mark : store.marks) {
    double nearest = std::numeric_limits<double>::infinity();
    for (const auto& t : mesh.triangles) {
      const Triangle tri{mesh.vertices[static_cast<std::size_t>(t[0])],
                         mesh.vertices[static_cast<std::size_t>(t[1])],
                         mesh.vertices[static_cast<std::size_t>(t[2])]};
      nearest =
          std::min(nearest, (closest_point_on_triangle(mark.p_body, tri) - mark.p_body).norm());
    }
    // The marks sit on vertices of the cylinder (their azimuths are multiples of 10 degrees):
    // float32 rounding of 0.15 m, and the survey's 6-digit coordinates (1e-6 m).
    EXPECT_LT(nearest, 2e-6) << "mark " << mark.id;
  }
}

}  // namespace
}  // namespace storetrack::clearance
