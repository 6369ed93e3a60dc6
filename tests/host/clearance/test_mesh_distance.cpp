// Mesh distance through the trees against closed forms (docs/clearance.md, "Tests"):
// sphere (meshed) - plane with the mesh's own tolerance derived from its facets, box - box
// (face, corner, edge - edge, overlap), a fin's tip edge against a plane, and the trees against
// the exhaustive minimum over all triangle pairs.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numbers>
#include <random>

#include "storetrack/clearance/mesh_bvh.hpp"
#include "synthetic_meshes.hpp"

namespace storetrack::clearance {
namespace {

using geometry::Transform;
using geometry::Vec3;

/// Rounding of a distance between points of size up to ~10 m: a few ulps of 10.
constexpr double kRounding = 1e-13;

MeshPair distance(const TriangleMesh& store_s, const Transform& T_p_s,
                  const TriangleMesh& aircraft_p) {
  return closest_pair(MeshBvh(store_s), T_p_s, MeshBvh(aircraft_p));
}

// The plane z = 0 of frame p; the store hangs above it at negative z... any side will do: the
// tests put the plane below the body (larger z, frame z down).
TEST(MeshDistance, SpherePoleDownAgainstPlaneIsExact) {
  const TriangleMesh sphere = test::uv_sphere({0, 0, 0}, 0.2, 24, 48);
  const TriangleMesh plane = test::plane_patch(0, 0, 0, 2, 8);
  // The +z pole is a vertex: centre at z = -0.55 puts it 0.35 from the plane (z down: above).
  const MeshPair p =
      distance(sphere, geometry::make_transform({0, 0, 0}, {0.1, -0.3, -0.55}), plane);
  EXPECT_NEAR(p.closest.distance, 0.35, kRounding);
  EXPECT_NEAR(p.closest.p_a.z(), -0.35, kRounding);
  EXPECT_NEAR(p.closest.p_b.z(), 0.0, kRounding);
  EXPECT_NEAR(p.closest.p_a.x(), 0.1, kRounding);
}

TEST(MeshDistance, SphereInAnyAttitudeIsWithinItsFacetTolerance) {
  // The meshed sphere lies between radius R (its vertices) and R - s, s = R - (the smallest
  // distance of a facet's plane from the centre): its lowest point is in [h - R, h - R + s].
  const double R = 0.2;
  const TriangleMesh sphere = test::uv_sphere({0, 0, 0}, R, 24, 48);
  double inner = R;
  for (const auto& t : sphere.triangles) {
    const Vec3 a = sphere.vertices[static_cast<std::size_t>(t[0])];
    const Vec3 n = (sphere.vertices[static_cast<std::size_t>(t[1])] - a)
                       .cross(sphere.vertices[static_cast<std::size_t>(t[2])] - a)
                       .normalized();
    inner = std::min(inner, std::abs(n.dot(a)));
  }
  const double sagitta = R - inner;
  ASSERT_GT(sagitta, 0.0);
  ASSERT_LT(sagitta, 2e-3);
  const TriangleMesh plane = test::plane_patch(0, 0, 0, 2, 8);
  const MeshBvh sphere_tree(sphere), plane_tree(plane);
  std::mt19937_64 rng(27);
  std::normal_distribution<double> normal;
  for (int i = 0; i < 200; ++i) {
    const Vec3 rotvec(normal(rng), normal(rng), normal(rng));
    const double h = 0.25 + 0.01 * i;  // centre height above the plane
    const MeshPair p =
        closest_pair(sphere_tree, geometry::make_transform(rotvec, {0.3, 0.1, -h}), plane_tree);
    EXPECT_GE(p.closest.distance, h - R - kRounding);
    EXPECT_LE(p.closest.distance, h - R + sagitta + kRounding);
  }
}

TEST(MeshDistance, BoxFacesAndCorners) {
  const TriangleMesh a = test::box({0, 0, 0}, {1, 0.5, 0.25});
  const TriangleMesh b = test::box({0, 0, 0}, {0.3, 0.2, 0.1});
  // Face to face along x: gap 0.07 between x = 1 and x = 1.3 - 0.3 + 0.07 ...
  const MeshPair face = distance(b, geometry::make_transform({0, 0, 0}, {1.37, 0.1, 0.05}), a);
  EXPECT_NEAR(face.closest.distance, 0.07, kRounding);
  // Corner to corner: gaps 0.1, 0.2, 0.3 along x, y, z.
  const MeshPair corner = distance(b, geometry::make_transform({0, 0, 0}, {1.4, 0.9, 0.65}), a);
  EXPECT_NEAR(corner.closest.distance, std::sqrt(0.01 + 0.04 + 0.09), kRounding);
  EXPECT_LT((corner.closest.p_b - Vec3(1, 0.5, 0.25)).norm(), kRounding);
  EXPECT_LT((corner.closest.p_a - Vec3(1.1, 0.7, 0.55)).norm(), kRounding);
}

TEST(MeshDistance, CrossedBoxEdgesAreAnEdgeEdgeContact) {
  // Cube A (half side a) rolled 45 deg about x: top edge along x at z = a sqrt 2. Cube B (half
  // side b) pitched 45 deg about y: bottom edge along y at z = centre - b sqrt 2. Gap g.
  const double a = 0.5, b = 0.3, g = 0.0125;
  const TriangleMesh A =
      test::posed(test::box({0, 0, 0}, {a, a, a}),
                  geometry::make_transform({std::numbers::pi / 4, 0, 0}, {0, 0, 0}));
  const Transform T_p_s = geometry::make_transform(
      {0, std::numbers::pi / 4, 0}, {0.05, -0.02, a * std::sqrt(2.0) + b * std::sqrt(2.0) + g});
  const MeshPair p = distance(test::box({0, 0, 0}, {b, b, b}), T_p_s, A);
  EXPECT_NEAR(p.closest.distance, g, 1e-12);
  EXPECT_EQ(p.closest.feature, Feature::kEdgeEdge);
  EXPECT_NEAR(p.closest.p_b.y(), 0.0, 1e-12);   // on A's edge (y = 0)
  EXPECT_NEAR(p.closest.p_a.x(), 0.05, 1e-12);  // on B's edge (x = 0.05)
}

TEST(MeshDistance, OverlappingBoxesAreAPenetration) {
  const TriangleMesh a = test::box({0, 0, 0}, {1, 0.5, 0.25});
  const TriangleMesh b = test::box({0, 0, 0}, {0.3, 0.2, 0.1});
  const MeshPair p = distance(b, geometry::make_transform({0.1, 0.2, 0}, {1.29, 0.1, 0.05}), a);
  EXPECT_EQ(p.closest.distance, 0.0);
  EXPECT_EQ(p.closest.feature, Feature::kPenetration);
}

TEST(MeshDistance, FinTipEdgeAgainstPlane) {
  // A fin (closed prism) rolled and pitched: the lowest of its six corners is the distance to
  // the plane below it (a convex body over a plane larger than it).
  const TriangleMesh fin = test::fin({0, 0, 0}, {0.4, 0, 0}, {0.4, 0, 0.3}, Vec3::UnitY(), 0.008);
  const TriangleMesh plane = test::plane_patch(0, 0, 0, 3, 6);
  for (const Vec3& rotvec : {Vec3(0, 0, 0), Vec3(0.1, -0.05, 0.3), Vec3(-0.02, 0.2, 1.0)}) {
    const Transform T_p_s = geometry::make_transform(rotvec, {0.2, 0.1, -0.5});
    double lowest = std::numeric_limits<double>::infinity();
    for (const Vec3& q : fin.vertices)
      lowest = std::min(lowest, -(T_p_s * q).z());
    const MeshPair p = distance(fin, T_p_s, plane);
    EXPECT_NEAR(p.closest.distance, lowest, kRounding) << rotvec.transpose();
  }
}

// The exhaustive minimum is 10^5-10^6 triangle pairs a pose: under ASan/UBSan a coarser pair
// of meshes and fewer poses keep it a smoke run (the trees' code paths are the same).
#ifdef STORETRACK_SANITIZE
constexpr int kExhaustivePoses = 2, kMeshSteps = 8;
#else
constexpr int kExhaustivePoses = 10, kMeshSteps = 20;
#endif

TEST(MeshDistance, TreesAgreeWithTheExhaustiveMinimum) {
  const TriangleMesh store = test::store(3.0, 0.2, kMeshSteps, 16);
  const TriangleMesh wing = test::aircraft(kMeshSteps, kMeshSteps, 0.6);
  const MeshBvh store_tree(store), wing_tree(wing);
  std::mt19937_64 rng(2027);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int i = 0; i < kExhaustivePoses; ++i) {
    const Transform T_p_s =
        geometry::make_transform({0.1 * u(rng), 0.1 * u(rng), 0.3 * u(rng)},
                                 {-1.5 + u(rng), 0.5 * u(rng), 0.3 + 0.2 * u(rng)});
    double exhaustive = std::numeric_limits<double>::infinity();
    for (const auto& ts : store.triangles) {
      const Triangle a = {T_p_s * store.vertices[static_cast<std::size_t>(ts[0])],
                          T_p_s * store.vertices[static_cast<std::size_t>(ts[1])],
                          T_p_s * store.vertices[static_cast<std::size_t>(ts[2])]};
      for (const auto& tw : wing.triangles) {
        const Triangle b = {wing.vertices[static_cast<std::size_t>(tw[0])],
                            wing.vertices[static_cast<std::size_t>(tw[1])],
                            wing.vertices[static_cast<std::size_t>(tw[2])]};
        exhaustive = std::min(exhaustive, triangle_distance(a, b).distance);
      }
    }
    const MeshPair p = closest_pair(store_tree, T_p_s, wing_tree);
    EXPECT_NEAR(p.closest.distance, exhaustive, kRounding) << i;
    EXPECT_NEAR((p.closest.p_a - p.closest.p_b).norm(), p.closest.distance, kRounding);
  }
}

}  // namespace
}  // namespace storetrack::clearance
