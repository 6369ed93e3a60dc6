// The clearance geometry file: strict fields (file and field named), units and frames applied,
// the plausibility check on extent (a mesh in the wrong units), closedness where required.
#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <string>

#include "storetrack/clearance/clearance.hpp"
#include "storetrack/clearance/geometry_file.hpp"
#include "storetrack/json/strict_reader.hpp"
#include "synthetic_meshes.hpp"

namespace storetrack::clearance {
namespace {

namespace fs = std::filesystem;

class GeometryFile : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("storetrack_clearance_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
    // A 3 m x 0.4 m x 0.4 m store written in millimetres, a 2 m pylon box in metres.
    test::write_file(path("store_mm.stl"),
                     test::stl_binary(test::box({1500, 0, 0}, {1500, 200, 200})));
    test::write_file(path("store_m.stl"),
                     test::stl_binary(test::box({1.5, 0, 0}, {1.5, 0.2, 0.2})));
    test::write_file(path("pylon.stl"), test::stl_ascii(test::box({1, 0, -0.6}, {1, 0.1, 0.3})));
    test::write_file(path("wing.stl"), test::stl_binary(test::plane_patch(0, 0, -1, 4, 4)));
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  std::string write_geometry(const std::string& bodies) const {
    const std::string file = path("geometry.json");
    test::write_file(file, R"({"format": "storetrack-clearance-geometry", "version": 1,
                              "name": "test", "bodies": [)" +
                               bodies + "]}");
    return file;
  }

  fs::path dir_;
};

constexpr const char* kStoreMm =
    R"({"name": "store", "stl": "store_mm.stl", "units": "mm", "frame": "store", "closed": true})";
constexpr const char* kPylon =
    R"({"name": "pylon", "stl": "pylon.stl", "units": "m", "frame": "pylon", "closed": true})";

TEST_F(GeometryFile, BodiesAreReadScaledAndMovedIntoTheirFrames) {
  const std::string file =
      write_geometry(std::string(kStoreMm) + "," + kPylon +
                     R"(, {"name": "wing", "stl": "wing.stl", "units": "m", "frame": "aircraft",
            "closed": false, "extent_range_m": [1, 20]})");
  const GeometryDescription g = read_geometry(file);
  ASSERT_EQ(g.bodies.size(), 3u);
  EXPECT_EQ(g.bodies[0].stl_path, path("store_mm.stl"));
  EXPECT_DOUBLE_EQ(g.bodies[0].scale_to_m, 1e-3);
  const Body store = load_body(g.bodies[0]);
  EXPECT_NEAR(largest_extent(store.mesh), 3.0, 1e-12);
  // The wing in the aircraft frame, 1 m below... moved by T_p_w = 0.5 m along z.
  const geometry::Transform T_p_w = geometry::make_transform({0, 0, 0}, {0, 0, 0.5});
  const Body wing = load_body(g.bodies[2], T_p_w);
  for (const geometry::Vec3& p : wing.mesh.vertices)
    EXPECT_DOUBLE_EQ(p.z(), -0.5);
  const ClearanceModel model = ClearanceModel::load(file, T_p_w);
  EXPECT_EQ(model.store_parts(), 1u);
  EXPECT_EQ(model.aircraft_parts(), 2u);
}

TEST_F(GeometryFile, StoreInMillimetresDeclaredInMetresIsRefusedAsImplausible) {
  const std::string file = write_geometry(
      R"({"name": "store", "stl": "store_mm.stl", "units": "m", "frame": "store",
          "closed": true},)" +
      std::string(kPylon));
  const GeometryDescription g = read_geometry(file);
  try {
    load_body(g.bodies[0]);
    FAIL() << "a 3000 m store was accepted";
  } catch (const MeshError& e) {
    EXPECT_EQ(e.file(), path("store_mm.stl"));
    EXPECT_NE(e.reason().find("implausible size: the largest side of its bounding box is 3000 m"),
              std::string::npos)
        << e.what();
    EXPECT_NE(e.reason().find("bodies[0]"), std::string::npos) << e.what();
  }
  // The reverse: metres declared as millimetres, a 3 mm store.
  const std::string reverse = write_geometry(
      R"({"name": "store", "stl": "store_m.stl", "units": "mm", "frame": "store",
          "closed": true},)" +
      std::string(kPylon));
  EXPECT_THROW(load_body(read_geometry(reverse).bodies[0]), MeshError);
}

TEST_F(GeometryFile, StatedExtentRangeIsApplied) {
  const std::string file = write_geometry(
      R"({"name": "store", "stl": "store_m.stl", "units": "m", "frame": "store",
          "closed": true, "extent_range_m": [0.5, 2.5]},)" +
      std::string(kPylon));
  EXPECT_THROW(load_body(read_geometry(file).bodies[0]), MeshError);  // 3 m > 2.5 m
}

TEST_F(GeometryFile, OpenMeshWhereClosedIsRequiredIsRefused) {
  const std::string file = write_geometry(
      std::string(kStoreMm) +
      R"(, {"name": "wing", "stl": "wing.stl", "units": "m", "frame": "pylon", "closed": true})");
  EXPECT_THROW(load_body(read_geometry(file).bodies[1]), MeshError);
}

TEST_F(GeometryFile, AircraftFrameBodyWithoutTheTransformIsRefused) {
  const std::string file = write_geometry(
      std::string(kStoreMm) +
      R"(, {"name": "wing", "stl": "wing.stl", "units": "m", "frame": "aircraft", "closed": false})");
  try {
    load_body(read_geometry(file).bodies[1]);
    FAIL();
  } catch (const MeshError& e) {
    EXPECT_NE(e.reason().find("no T_p_w"), std::string::npos) << e.what();
  }
}

/// The FieldError text of a geometry file with these bodies.
std::string field_refusal(const std::string& file) {
  try {
    read_geometry(file);
  } catch (const jsonfile::FieldError& e) {
    return e.what();
  }
  return "accepted";
}

TEST_F(GeometryFile, BadFieldsAreRefusedNamingFileAndField) {
  const std::string units = field_refusal(write_geometry(
      R"({"name": "store", "stl": "store_mm.stl", "units": "inch", "frame": "store",
          "closed": true},)" +
      std::string(kPylon)));
  EXPECT_NE(units.find("geometry.json: bodies[0].units: unknown units 'inch'"), std::string::npos)
      << units;
  const std::string frame = field_refusal(write_geometry(
      std::string(kStoreMm) +
      R"(, {"name": "pylon", "stl": "pylon.stl", "units": "m", "frame": "wing", "closed": true})"));
  EXPECT_NE(frame.find("bodies[1].frame: unknown frame 'wing'"), std::string::npos) << frame;
  const std::string typo = field_refusal(write_geometry(
      std::string(kStoreMm) +
      R"(, {"name": "pylon", "stl": "pylon.stl", "units": "m", "frame": "pylon", "closd": true})"));
  EXPECT_NE(typo.find("bodies[1]"), std::string::npos) << typo;
  const std::string no_aircraft = field_refusal(write_geometry(
      std::string(kStoreMm) + "," +
      R"({"name": "fin", "stl": "store_mm.stl", "units": "mm", "frame": "store", "closed": true})"));
  EXPECT_NE(no_aircraft.find("bodies: needs at least one body"), std::string::npos) << no_aircraft;
  const std::string twice = field_refusal(write_geometry(std::string(kStoreMm) + "," + kStoreMm));
  EXPECT_NE(twice.find("already the name"), std::string::npos) << twice;
  const std::string comma = field_refusal(write_geometry(
      std::string(kStoreMm) +
      R"(, {"name": "pylon, left", "stl": "pylon.stl", "units": "m", "frame": "pylon", "closed": true})"));
  EXPECT_NE(comma.find("bodies[1].name: a body name must not hold a comma"), std::string::npos)
      << comma;
}

}  // namespace
}  // namespace storetrack::clearance
