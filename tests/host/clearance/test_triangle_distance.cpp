// The exact triangle distance primitives against closed forms: point-triangle in each Voronoi
// region, segment-segment (skew, parallel, degenerate), triangle pairs in the vertex-face,
// edge-edge and intersecting configurations.
#include <gtest/gtest.h>

#include <cmath>

#include "storetrack/clearance/triangle_distance.hpp"

namespace storetrack::clearance {
namespace {

using geometry::Vec3;

constexpr double kTol = 1e-14;

const Triangle kUnit = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0)};

TEST(PointTriangle, EachRegionGivesItsClosedForm) {
  EXPECT_LT((closest_point_on_triangle({0.2, 0.3, 5}, kUnit) - Vec3(0.2, 0.3, 0)).norm(), kTol);
  EXPECT_LT((closest_point_on_triangle({-1, -2, 1}, kUnit) - Vec3(0, 0, 0)).norm(), kTol);
  EXPECT_LT((closest_point_on_triangle({3, -1, 0}, kUnit) - Vec3(1, 0, 0)).norm(), kTol);
  EXPECT_LT((closest_point_on_triangle({0.5, -1, 2}, kUnit) - Vec3(0.5, 0, 0)).norm(), kTol);
  EXPECT_LT((closest_point_on_triangle({-1, 0.25, 0}, kUnit) - Vec3(0, 0.25, 0)).norm(), kTol);
  // Hypotenuse x + y = 1: the foot of (1, 1, 0) is (0.5, 0.5, 0).
  EXPECT_LT((closest_point_on_triangle({1, 1, -3}, kUnit) - Vec3(0.5, 0.5, 0)).norm(), kTol);
}

TEST(SegmentSegment, SkewParallelAndDegenerate) {
  Vec3 a, b;
  // Skew: x axis segment and a y-direction segment 2 above at x = 0.3.
  closest_points_of_segments({-1, 0, 0}, {1, 0, 0}, {0.3, -1, 2}, {0.3, 1, 2}, a, b);
  EXPECT_LT((a - Vec3(0.3, 0, 0)).norm(), kTol);
  EXPECT_LT((b - Vec3(0.3, 0, 2)).norm(), kTol);
  // Beyond the ends: closest at end points.
  closest_points_of_segments({0, 0, 0}, {1, 0, 0}, {2, 1, 0}, {2, 3, 0}, a, b);
  EXPECT_NEAR((a - b).norm(), std::sqrt(2.0), kTol);
  // Parallel, overlapping: distance is the separation.
  closest_points_of_segments({0, 0, 0}, {2, 0, 0}, {1, 0, 0.5}, {3, 0, 0.5}, a, b);
  EXPECT_NEAR((a - b).norm(), 0.5, kTol);
  // A point against a segment.
  closest_points_of_segments({0.5, 2, 0}, {0.5, 2, 0}, {0, 0, 0}, {1, 0, 0}, a, b);
  EXPECT_NEAR((a - b).norm(), 2.0, kTol);
}

TEST(TriangleDistance, VertexAboveFace) {
  const Triangle above = {Vec3(0.2, 0.2, 0.7), Vec3(0.2, 0.2, 2), Vec3(0.5, 0.1, 3)};
  const ClosestPair c = triangle_distance(above, kUnit);
  EXPECT_NEAR(c.distance, 0.7, kTol);
  EXPECT_EQ(c.feature, Feature::kVertexFace);
  EXPECT_LT((c.p_b - Vec3(0.2, 0.2, 0)).norm(), kTol);
  const ClosestPair swapped = triangle_distance(kUnit, above);
  EXPECT_EQ(swapped.feature, Feature::kFaceVertex);
  EXPECT_NEAR(swapped.distance, 0.7, kTol);
}

TEST(TriangleDistance, CrossedEdges) {
  // a's edge along y at x = 0.3, z = 0.4 above kUnit's region... crossing kUnit's edge y = 0
  // outside the face: a vertical triangle whose lower edge runs along y below y = 0.
  const Triangle a = {Vec3(0.5, -2, 0.25), Vec3(0.5, -0.5, -0.25), Vec3(0.5, -2, -2)};
  // Closest: a's edge (0.5,-2,0.25)-(0.5,-0.5,-0.25) vs kUnit's edge y = 0? Solve by sampling.
  const ClosestPair c = triangle_distance(a, kUnit);
  double brute = 1e9;
  for (int i = 0; i <= 400; ++i)
    for (int j = 0; i + j <= 400; ++j) {
      const Vec3 pa = a[0] + (a[1] - a[0]) * i / 400.0 + (a[2] - a[0]) * j / 400.0;
      brute = std::min(brute, (pa - closest_point_on_triangle(pa, kUnit)).norm());
    }
  EXPECT_LE(c.distance, brute + kTol);
  EXPECT_GT(c.distance, brute - 1e-2);  // the sampled surface is within its grid of the truth
}

TEST(TriangleDistance, EdgeEdgeClosedForm) {
  // Two triangles whose nearest features are skew edges 0.3 apart: a's edge along x at z = 0.3
  // (its face rising above), b's edge along y at z = 0 (its face falling below).
  const Triangle a = {Vec3(-1, 0, 0.3), Vec3(1, 0, 0.3), Vec3(0, 0, 1.3)};
  const Triangle b = {Vec3(0.2, -1, 0), Vec3(0.2, 1, 0), Vec3(0.2, 0, -1)};
  const ClosestPair c = triangle_distance(a, b);
  EXPECT_NEAR(c.distance, 0.3, kTol);
  EXPECT_EQ(c.feature, Feature::kEdgeEdge);
  EXPECT_LT((c.p_a - Vec3(0.2, 0, 0.3)).norm(), kTol);
  EXPECT_LT((c.p_b - Vec3(0.2, 0, 0)).norm(), kTol);
}

TEST(TriangleDistance, PiercingTrianglesAreAPenetrationAtZero) {
  // b stands through the middle of kUnit: no vertex or edge pair at distance 0 is needed.
  const Triangle b = {Vec3(0.25, 0.25, -1), Vec3(0.3, 0.2, 1), Vec3(0.2, 0.3, 1)};
  const ClosestPair c = triangle_distance(kUnit, b);
  EXPECT_EQ(c.distance, 0.0);
  EXPECT_EQ(c.feature, Feature::kPenetration);
  EXPECT_NEAR(c.p_a.z(), 0.0, kTol);
  // Coplanar overlapping triangles: distance 0 from an edge crossing.
  const Triangle shifted = {Vec3(0.5, -0.5, 0), Vec3(0.5, 0.5, 0), Vec3(-0.5, 0.5, 0)};
  EXPECT_EQ(triangle_distance(kUnit, shifted).distance, 0.0);
}

}  // namespace
}  // namespace storetrack::clearance
