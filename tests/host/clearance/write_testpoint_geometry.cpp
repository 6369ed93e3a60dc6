// Writes the store_separation scenario's clearance geometry (testpoint_geometry.hpp): four
// binary STL files and the geometry file naming them, into the folder given.
//   write_testpoint_geometry common/sim/scenarios/store_separation_geometry
#include <cstdio>
#include <string>

#include "testpoint_geometry.hpp"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: write_testpoint_geometry DIR\n");
    return 2;
  }
  const std::string dir = argv[1];
  const storetrack::test::TestpointGeometry g = storetrack::test::testpoint_geometry();
  using storetrack::test::stl_binary;
  storetrack::test::write_file(dir + "/store.stl",
                               stl_binary(g.store, "storetrack testpoint store"));
  storetrack::test::write_file(dir + "/pylon.stl",
                               stl_binary(g.pylon, "storetrack testpoint pylon"));
  storetrack::test::write_file(dir + "/wing_lower.stl",
                               stl_binary(g.wing_lower, "storetrack testpoint wing lower surface"));
  storetrack::test::write_file(dir + "/adjacent_store.stl",
                               stl_binary(g.adjacent_store, "storetrack testpoint adjacent store"));
  storetrack::test::write_file(dir + "/geometry.json",
                               R"json({"format": "storetrack-clearance-geometry", "version": 1,
 "name": "store_separation: the scenario's store with four fins against its pylon, the wing lower surface and the adjacent store (tests/host/clearance/testpoint_geometry.hpp)",
 "bodies": [{"name": "store", "stl": "store.stl", "units": "m", "frame": "store", "closed": false},
            {"name": "pylon", "stl": "pylon.stl", "units": "m", "frame": "pylon", "closed": true},
            {"name": "wing lower surface", "stl": "wing_lower.stl", "units": "m", "frame": "pylon", "closed": false},
            {"name": "adjacent store", "stl": "adjacent_store.stl", "units": "m", "frame": "pylon", "closed": false}]
}
)json");
  std::printf("%zu + %zu + %zu + %zu triangles written to %s\n", g.store.triangles.size(),
              g.pylon.triangles.size(), g.wing_lower.triangles.size(),
              g.adjacent_store.triangles.size(), dir.c_str());
  return 0;
}
