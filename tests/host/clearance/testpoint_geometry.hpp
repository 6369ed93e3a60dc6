// The clearance geometry of the store_separation scenario (tools/testpoint's main job; checked in
// under common/sim/scenarios/store_separation_geometry, written by write_testpoint_geometry):
// the scenario's store (store_shape: radius 0.15 m, nose at x = +1 m, tail at -1 m in frame s;
// its survey's marks on the cylinder at x = +-0.25 and +-0.75 m) with four tail fins, and, in
// the pylon frame (z down; the captive store's axis at z = 0.2 m), the pylon body above it, the
// wing lower surface above the pylon and an adjacent store on the next station inboard.
#pragma once

#include <numbers>

#include "synthetic_meshes.hpp"

namespace storetrack::test {

struct TestpointGeometry {
  TriangleMesh store, pylon, wing_lower, adjacent_store;
};

/// Captive: the store's top line at z = 0.2 - 0.15 = 0.05 m, the pylon's lower face at
/// z = 0: 5.0 cm of clearance, body to pylon (its fins clear the pylon's aft end).
inline constexpr double kTestpointPylonBottom_m = 0.0;
inline constexpr double kTestpointCaptiveClearance_m = 0.05;

inline TestpointGeometry testpoint_geometry() {
  // store(): nose at x = 0 towards +x; the scenario's frame s has the nose at +1 m, so turn it
  // half a turn about z and shift it by 1 m. Nose 0.2 m, boattail from 1.8 m: the marks at
  // x_s = +-0.75 m (generator x 0.25 and 1.75) lie on the cylinder. 36 segments put a vertex
  // at each mark's azimuth (multiples of 10 degrees) and on the top line (270 degrees).
  geometry::Transform T_s_gen = geometry::Transform::Identity();
  T_s_gen.linear() = Vec3(-1, -1, 1).asDiagonal();
  T_s_gen.translation() = Vec3(1, 0, 0);
  const TriangleMesh store_s = posed(store(2.0, 0.15, 30, 36, 0.1, 0.9), T_s_gen);
  TestpointGeometry g;
  g.store = store_s;
  // The pylon: 1.5 m long (x from -0.55 to 0.95, ahead of the fins), 0.16 m wide, from the
  // wing (z = -0.5) down to its lower face.
  g.pylon = box(Vec3(0.2, 0, (-0.5 + kTestpointPylonBottom_m) / 2), Vec3(0.75, 0.08, 0.25));
  g.wing_lower = plane_patch(0.5, 0, -0.5, 3.0, 8);
  geometry::Transform T_p_adjacent = geometry::Transform::Identity();
  T_p_adjacent.translation() = Vec3(0, -1.1, 0.2);
  g.adjacent_store = posed(store_s, T_p_adjacent);
  return g;
}

}  // namespace storetrack::test
