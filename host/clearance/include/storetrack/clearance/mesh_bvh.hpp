// An axis-aligned bounding-box tree over a mesh's triangles, in the mesh's own frame, and the
// exact minimum distance between a posed store mesh and an aircraft mesh through two such trees
// (docs/clearance.md, "Distance"). Built once per body; a query allocates nothing but the
// output of pairs_within.
#pragma once

#include <cstdint>
#include <vector>

#include "storetrack/clearance/mesh.hpp"
#include "storetrack/clearance/triangle_distance.hpp"

namespace storetrack::clearance {

class MeshBvh {
 public:
  /// Leaves hold at most kLeafTriangles triangles; split at the median of the triangle centroids
  /// along the longest side of their bounds.
  static constexpr int kLeafTriangles = 4;

  explicit MeshBvh(const TriangleMesh& mesh);

  struct Node {
    geometry::Vec3 centre = geometry::Vec3::Zero();
    geometry::Vec3 half = geometry::Vec3::Zero();  ///< half side lengths
    std::int32_t first = 0;                        ///< leaf: first triangle; inner: left child
    std::int32_t count = 0;                        ///< leaf: triangles; inner: 0 (right = left + 1)
  };
  const std::vector<Node>& nodes() const { return nodes_; }
  /// Triangles in tree order, and each one's index in the mesh (for reports).
  const std::vector<Triangle>& triangles() const { return triangles_; }
  const std::vector<std::int32_t>& mesh_index() const { return mesh_index_; }
  /// Each triangle's own box (tree order): lets a leaf pair skip triangles before the exact test.
  const std::vector<Eigen::AlignedBox3d>& triangle_boxes() const { return triangle_boxes_; }
  /// Each triangle's unit face normal (tree order): its plane's gap to another triangle is a
  /// second lower bound of their distance, tight where a vertex faces the face.
  const std::vector<geometry::Vec3>& face_normals() const { return face_normals_; }
  /// Largest distance of a vertex from the frame's origin (bounds the lever arm of a rotation).
  double radius() const { return radius_; }
  /// The same per node and per triangle (tree order): the lever arm of the points they hold.
  const std::vector<double>& node_radii() const { return node_radii_; }
  const std::vector<double>& triangle_radii() const { return triangle_radii_; }

 private:
  void build(std::int32_t node, std::int32_t first, std::int32_t count,
             const std::vector<Triangle>& by_mesh_index,
             const std::vector<geometry::Vec3>& centroids);

  std::vector<Node> nodes_;
  std::vector<Triangle> triangles_;
  std::vector<std::int32_t> mesh_index_;
  std::vector<Eigen::AlignedBox3d> triangle_boxes_;
  std::vector<geometry::Vec3> face_normals_;
  std::vector<double> node_radii_;
  std::vector<double> triangle_radii_;
  double radius_ = 0;
};

/// A pair of triangles, store (posed) and aircraft, and their closest points in the aircraft's
/// frame (the pylon frame p for the clearance).
struct MeshPair {
  ClosestPair closest;  ///< p_a on the store, p_b on the aircraft, both in frame p
  std::int32_t store_triangle = -1;
  std::int32_t aircraft_triangle = -1;
  geometry::Vec3 aircraft_face_normal = geometry::Vec3::UnitZ();  ///< unit, frame p
};

/// Minimum distance between store_s posed by T_p_s and aircraft_p.
MeshPair closest_pair(const MeshBvh& store_s, const geometry::Transform& T_p_s,
                      const MeshBvh& aircraft_p);

/// A pair of triangles by their places in the trees' order (-1: none).
struct TreePair {
  std::int32_t store = -1;
  std::int32_t aircraft = -1;
};

/// The same, warm-started: the distance of `previous` (the last sample's closest pair) at this
/// pose bounds the descent from its first node. The result is the one closest_pair gives (the
/// same pair, points and feature: docs/clearance.md, "Distance"); `previous` is set to it.
MeshPair closest_pair(const MeshBvh& store_s, const geometry::Transform& T_p_s,
                      const MeshBvh& aircraft_p, TreePair& previous);

/// Appends every pair of triangles at a distance below max_distance_m (the feature-switch pass).
void pairs_within(const MeshBvh& store_s, const geometry::Transform& T_p_s,
                  const MeshBvh& aircraft_p, double max_distance_m, std::vector<MeshPair>& out);

/// d(distance)/d(xi) for a left perturbation xi = (rx, ry, rz, tx, ty, tz) of T_p_s
/// (geometry::perturb_left): the store's closest point p moves by -[p - t]x phi + rho, so with
/// d = n . (p_store - p_aircraft), J = [((p_store - t_p_s) x n)^T, n^T].
geometry::Vec6 distance_jacobian(const geometry::Vec3& p_store_p, const geometry::Vec3& t_p_s,
                                 const geometry::Vec3& normal_p);

/// A reach that grows with the lever arm r: the largest distance, from the store's origin, of
/// the store points a node or triangle holds: base_m + sigmas * u(r), with u(r) a bound on the
/// distance's standard uncertainty of any pair whose store point is within r of the origin,
/// min(u_translation_m + u_rotation_rad r, sqrt(lambda_max (1 + r^2))) (docs/clearance.md).
/// With the covariance, the reach of one pair of triangles is also bounded by the direction
/// between their boxes (at(store_box, aircraft_box)); theirs is the smaller of the two.
struct LeverArmReach {
  double base_m = 0;
  double sigmas = 0;
  double u_translation_m = 0;  ///< sqrt of the largest eigenvalue of the translation block
  double u_rotation_rad = 0;   ///< sqrt of the largest eigenvalue of the rotation block
  double lambda_max = 0;       ///< largest eigenvalue of the whole 6x6 covariance
  /// The covariance of T_p_s's left perturbation and T_p_s's translation; null: no narrowing.
  const geometry::Mat6* cov = nullptr;
  geometry::Vec3 t_p_s = geometry::Vec3::Zero();
  double at(double lever_arm_m) const;
  /// The reach of the pairs whose store point is in `store_box` and aircraft point in
  /// `aircraft_box` (frame p), by their direction alone: u bounded by u at the boxes' centres plus
  /// how far J can move within them (docs/clearance.md, "Feature switch"); infinity where the
  /// boxes are too near for a bound (or without a covariance).
  double at(const Eigen::AlignedBox3d& store_box, const Eigen::AlignedBox3d& aircraft_box) const;
};

/// Appends every pair of triangles at a distance below its reach: the smaller of reach.at(r)
/// of its store triangle and reach.at of its two triangles' boxes (the feature-switch pass with
/// the reach taken per node and per pair; the same pairs pass its filter).
void pairs_within(const MeshBvh& store_s, const geometry::Transform& T_p_s,
                  const MeshBvh& aircraft_p, const LeverArmReach& reach,
                  std::vector<MeshPair>& out);

}  // namespace storetrack::clearance
