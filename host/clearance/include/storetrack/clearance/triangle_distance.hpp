// Exact distance between two triangles and between their sub-features (docs/clearance.md,
// "Distance"). Two disjoint triangles are closest either at a vertex of one against the other
// triangle, or between an edge of each; when neither is at distance 0 but an edge of one
// crosses the other, they intersect: distance 0, flagged as penetration.
#pragma once

#include <array>
#include <cstdint>

#include "storetrack/geometry/transform.hpp"

namespace storetrack::clearance {

using Triangle = std::array<geometry::Vec3, 3>;

/// The pair of features whose distance is the minimum. "a" is the first triangle (the store's).
enum class Feature : std::uint8_t {
  kVertexFace,   ///< a vertex of a against the face of b (its interior or boundary)
  kFaceVertex,   ///< the face of a against a vertex of b
  kEdgeEdge,     ///< an edge of a against an edge of b
  kPenetration,  ///< the triangles touch or intersect (distance 0)
};
const char* feature_name(Feature f);

struct ClosestPair {
  double distance = 0;
  geometry::Vec3 p_a = geometry::Vec3::Zero();  ///< on a
  geometry::Vec3 p_b = geometry::Vec3::Zero();  ///< on b
  Feature feature = Feature::kVertexFace;
};

/// The point of triangle t closest to p (Ericson, "Real-Time Collision Detection", 2005, 5.1.5).
geometry::Vec3 closest_point_on_triangle(const geometry::Vec3& p, const Triangle& t);

/// Closest points of segments [p0, p1] and [q0, q1] (Ericson 5.1.9; degenerate segments too).
void closest_points_of_segments(const geometry::Vec3& p0, const geometry::Vec3& p1,
                                const geometry::Vec3& q0, const geometry::Vec3& q1,
                                geometry::Vec3& on_p, geometry::Vec3& on_q);

/// Where segment [p0, p1] crosses the plane of t strictly between its ends and inside t (the
/// boundary included). Coplanar segments and touching ends are left to the distance tests.
bool segment_crosses_triangle(const geometry::Vec3& p0, const geometry::Vec3& p1, const Triangle& t,
                              geometry::Vec3& crossing);

/// Exact minimum distance between triangles a and b with the closest points.
ClosestPair triangle_distance(const Triangle& a, const Triangle& b);

}  // namespace storetrack::clearance
