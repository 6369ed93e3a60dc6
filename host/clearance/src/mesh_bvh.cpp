#include "storetrack/clearance/mesh_bvh.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace storetrack::clearance {
namespace {

using geometry::Mat3;
using geometry::Vec3;

/// Distance between two axis-aligned boxes given by centre and half sides (0 when they overlap).
double box_distance(const Vec3& c1, const Vec3& h1, const Vec3& c2, const Vec3& h2) {
  const Vec3 gap = ((c1 - c2).cwiseAbs() - h1 - h2).cwiseMax(0.0);
  return gap.norm();
}

/// Distance between two boxes: the box of a (posed) triangle, computed once for all the
/// triangles it meets in a leaf, and another triangle's: a lower bound of the triangles'
/// distance, which lets a leaf pair skip the exact test.
double triangle_box_distance(const Eigen::AlignedBox3d& posed, const Eigen::AlignedBox3d& box) {
  const Vec3 gap = (posed.min() - box.max()).cwiseMax(box.min() - posed.max()).cwiseMax(0.0);
  return gap.norm();
}

/// A face normal's rounding is at most ~eps / kDegenerateHeightRatio = 2.3e-10 rad for the
/// thinnest triangle a mesh may hold; times a lever of ~10 m that is 2.3e-9 m: 0.1 um is above
/// it, and far below any distance difference the pruning is for.
constexpr double kPlaneGapMargin_m = 1e-7;

Vec3 face_normal(const Triangle& t) {
  return (t[1] - t[0]).cross(t[2] - t[0]).normalized();
}

/// Gap between the plane through `on_plane` with unit normal n and a triangle wholly on one side
/// of it (0 when it crosses): a lower bound of the distance from the plane's triangle to it.
/// Lowered by kPlaneGapMargin_m so that rounding never lifts it above the exact test's distance.
double plane_gap(const Vec3& n, const Vec3& on_plane, const Triangle& t) {
  const double h0 = n.dot(t[0] - on_plane), h1 = n.dot(t[1] - on_plane),
               h2 = n.dot(t[2] - on_plane);
  return std::max({std::min({h0, h1, h2}), std::min({-h0, -h1, -h2}), 0.0}) - kPlaneGapMargin_m;
}

/// Gap between two triangles projected on the line through their centroids (0 when the
/// projections overlap): a lower bound of their distance (any direction gives one), tight for
/// triangles far apart beside their size, where the boxes' gap and the face planes are loose
/// when the two are offset sideways (a store falling past another one metres away). Lowered by
/// kPlaneGapMargin_m, as plane_gap.
double centroid_line_gap(const Triangle& s, const Triangle& a) {
  const Vec3 between = (s[0] + s[1] + s[2]) - (a[0] + a[1] + a[2]);
  const double length = between.norm();
  if (!(length > 0)) return 0.0;
  const Vec3 n = between / length;
  const double s_lowest = std::min({n.dot(s[0]), n.dot(s[1]), n.dot(s[2])});
  const double a_highest = std::max({n.dot(a[0]), n.dot(a[1]), n.dot(a[2])});
  return std::max(s_lowest - a_highest, 0.0) - kPlaneGapMargin_m;
}

/// A store node's box in frame p: the box of its rotated box (centre R c + t, half |R| h).
struct PosedBox {
  Vec3 centre, half;
};

/// Branch and bound over both trees. The visitor's bound(r) is the distance beyond which a pair
/// of nodes or triangles cannot matter, r the largest distance of the store node's or
/// triangle's points from the store's origin (computed only when Visitor::kUsesLeverArm);
/// accept() takes each triangle pair nearer than bound(r), with its places in the trees.
template <typename Visitor>
class DualTraversal {
 public:
  DualTraversal(const MeshBvh& store, const geometry::Transform& T_p_s, const MeshBvh& aircraft,
                Visitor& visitor)
      : store_(store),
        aircraft_(aircraft),
        R_(T_p_s.linear()),
        t_(T_p_s.translation()),
        abs_R_(R_.cwiseAbs()),
        visitor_(visitor) {}

  void run() { visit(0, posed(0), 0); }

  /// The pair of the trees' triangles i (store) and j (aircraft), the store's posed.
  MeshPair pair(std::int32_t i, std::int32_t j) const {
    const auto k = static_cast<std::size_t>(j);
    return {triangle_distance(posed_triangle(i), aircraft_.triangles()[k]),
            store_.mesh_index()[static_cast<std::size_t>(i)], aircraft_.mesh_index()[k],
            aircraft_.face_normals()[k]};
  }

  Triangle posed_triangle(std::int32_t i) const {
    const Triangle& q = store_.triangles()[static_cast<std::size_t>(i)];
    return {R_ * q[0] + t_, R_ * q[1] + t_, R_ * q[2] + t_};
  }

 private:
  /// Tests the triangles of two leaves; bound() is asked again for every pair because accept()
  /// may lower it. The feature-switch pass (a visitor that uses the lever arm) narrows it by
  /// pair_bound() for the pairs the cheap gaps keep, before the exact test.
  void leaf(const MeshBvh::Node& sn, const MeshBvh::Node& an) {
    for (std::int32_t i = sn.first; i < sn.first + sn.count; ++i) {
      const Triangle ts = posed_triangle(i);
      const Eigen::AlignedBox3d ts_box(ts[0].cwiseMin(ts[1]).cwiseMin(ts[2]),
                                       ts[0].cwiseMax(ts[1]).cwiseMax(ts[2]));
      const Vec3 ns = R_ * store_.face_normals()[static_cast<std::size_t>(i)];
      const double lever = triangle_lever_arm(i);
      for (std::int32_t j = an.first; j < an.first + an.count; ++j) {
        const auto k = static_cast<std::size_t>(j);
        const Triangle& ta = aircraft_.triangles()[k];
        const Eigen::AlignedBox3d& ta_box = aircraft_.triangle_boxes()[k];
        double bound = visitor_.bound(lever);
        double lower = 0;
        const auto beyond = [&](double gap) {
          lower = std::max(lower, gap);
          return lower >= bound;
        };
        if (beyond(triangle_box_distance(ts_box, ta_box)) ||
            beyond(plane_gap(aircraft_.face_normals()[k], ta[0], ts)) ||
            beyond(plane_gap(ns, ts[0], ta)) || beyond(centroid_line_gap(ts, ta)))
          continue;
        if constexpr (Visitor::kUsesLeverArm) {
          bound = std::min(bound, visitor_.pair_bound(ts_box, ta_box));
          if (lower >= bound) continue;
        }
        const ClosestPair c = triangle_distance(ts, ta);
        if (c.distance < bound)
          visitor_.accept({c, store_.mesh_index()[static_cast<std::size_t>(i)],
                           aircraft_.mesh_index()[k], aircraft_.face_normals()[k]},
                          {i, j});
      }
    }
  }

  double triangle_lever_arm(std::int32_t i) const {
    if constexpr (!Visitor::kUsesLeverArm) return 0.0;
    return store_.triangle_radii()[static_cast<std::size_t>(i)];
  }

  /// bound() for the pairs under store node s.
  double bound(std::int32_t s) const {
    if constexpr (!Visitor::kUsesLeverArm) return visitor_.bound(0.0);
    return visitor_.bound(store_.node_radii()[static_cast<std::size_t>(s)]);
  }

  PosedBox posed(std::int32_t s) const {
    const MeshBvh::Node& n = store_.nodes()[static_cast<std::size_t>(s)];
    return {R_ * n.centre + t_, abs_R_ * n.half};
  }

  double distance(const PosedBox& s, std::int32_t a) const {
    const MeshBvh::Node& n = aircraft_.nodes()[static_cast<std::size_t>(a)];
    return box_distance(s.centre, s.half, n.centre, n.half);
  }

  void visit(std::int32_t s, const PosedBox& sbox, std::int32_t a) {
    const MeshBvh::Node& sn = store_.nodes()[static_cast<std::size_t>(s)];
    const MeshBvh::Node& an = aircraft_.nodes()[static_cast<std::size_t>(a)];
    const bool s_leaf = sn.count > 0, a_leaf = an.count > 0;
    if (s_leaf && a_leaf) {
      leaf(sn, an);
      return;
    }
    // Descend the larger node (the aircraft's when the store's is a leaf), nearer child first.
    const bool split_store = !s_leaf && (a_leaf || sn.half.squaredNorm() >= an.half.squaredNorm());
    if (split_store) {
      const PosedBox b0 = posed(sn.first), b1 = posed(sn.first + 1);
      double d0 = distance(b0, a), d1 = distance(b1, a);
      if (d1 < d0) {
        if (d1 < bound(sn.first + 1)) visit(sn.first + 1, b1, a);
        if (d0 < bound(sn.first)) visit(sn.first, b0, a);
      } else {
        if (d0 < bound(sn.first)) visit(sn.first, b0, a);
        if (d1 < bound(sn.first + 1)) visit(sn.first + 1, b1, a);
      }
    } else {
      const double d0 = distance(sbox, an.first), d1 = distance(sbox, an.first + 1);
      if (d1 < d0) {
        if (d1 < bound(s)) visit(s, sbox, an.first + 1);
        if (d0 < bound(s)) visit(s, sbox, an.first);
      } else {
        if (d0 < bound(s)) visit(s, sbox, an.first);
        if (d1 < bound(s)) visit(s, sbox, an.first + 1);
      }
    }
  }

  const MeshBvh& store_;
  const MeshBvh& aircraft_;
  const Mat3 R_;
  const Vec3 t_;
  const Mat3 abs_R_;
  Visitor& visitor_;
};

struct ClosestVisitor {
  static constexpr bool kUsesLeverArm = false;
  MeshPair best;
  TreePair best_in_trees;

  double bound(double /*lever_arm*/) const { return best.closest.distance; }
  void accept(const MeshPair& pair, TreePair in_trees) {
    best = pair;
    best_in_trees = in_trees;
  }
};

struct WithinVisitor {
  static constexpr bool kUsesLeverArm = false;
  double max_distance;
  std::vector<MeshPair>& out;

  double bound(double /*lever_arm*/) const { return max_distance; }
  void accept(const MeshPair& pair, TreePair /*in_trees*/) { out.push_back(pair); }
};

struct LeverArmWithinVisitor {
  static constexpr bool kUsesLeverArm = true;
  const LeverArmReach& reach;
  std::vector<MeshPair>& out;

  double bound(double lever_arm) const { return reach.at(lever_arm); }
  double pair_bound(const Eigen::AlignedBox3d& store, const Eigen::AlignedBox3d& aircraft) const {
    return reach.at(store, aircraft);
  }
  void accept(const MeshPair& pair, TreePair /*in_trees*/) { out.push_back(pair); }
};

}  // namespace

MeshBvh::MeshBvh(const TriangleMesh& mesh) {
  const std::size_t n = mesh.triangles.size();
  if (n == 0) throw MeshError(mesh.source, std::nullopt, "no triangles");
  std::vector<Triangle> by_mesh_index(n);
  std::vector<Vec3> centroids(n);
  for (std::size_t t = 0; t < n; ++t) {
    for (std::size_t k = 0; k < 3; ++k)
      by_mesh_index[t][k] = mesh.vertices[static_cast<std::size_t>(mesh.triangles[t][k])];
    centroids[t] = (by_mesh_index[t][0] + by_mesh_index[t][1] + by_mesh_index[t][2]) / 3.0;
  }
  for (const Vec3& p : mesh.vertices)
    radius_ = std::max(radius_, p.norm());
  mesh_index_.resize(n);
  std::iota(mesh_index_.begin(), mesh_index_.end(), 0);
  nodes_.reserve(2 * n);
  nodes_.emplace_back();
  build(0, 0, static_cast<std::int32_t>(n), by_mesh_index, centroids);
  triangles_.reserve(n);
  triangle_boxes_.reserve(n);
  face_normals_.reserve(n);
  for (const std::int32_t t : mesh_index_) {
    triangles_.push_back(by_mesh_index[static_cast<std::size_t>(t)]);
    const Triangle& tri = triangles_.back();
    face_normals_.push_back(face_normal(tri));
    triangle_boxes_.emplace_back(tri[0].cwiseMin(tri[1]).cwiseMin(tri[2]),
                                 tri[0].cwiseMax(tri[1]).cwiseMax(tri[2]));
    triangle_radii_.push_back(std::max({tri[0].norm(), tri[1].norm(), tri[2].norm()}));
  }
  // Children come after their parent in nodes_: from the back, each node's children are done.
  node_radii_.assign(nodes_.size(), 0.0);
  for (std::size_t i = nodes_.size(); i-- > 0;) {
    const Node& node = nodes_[i];
    const auto first = static_cast<std::size_t>(node.first);
    node_radii_[i] = node.count > 0
                         ? *std::max_element(triangle_radii_.begin() + node.first,
                                             triangle_radii_.begin() + node.first + node.count)
                         : std::max(node_radii_[first], node_radii_[first + 1]);
  }
}

// Fills nodes_[node] with the triangles mesh_index_[first, first + count); the children of an
// inner node are appended as a pair, so that right = left + 1.
void MeshBvh::build(std::int32_t node, std::int32_t first, std::int32_t count,
                    const std::vector<Triangle>& by_mesh_index,
                    const std::vector<Vec3>& centroids) {
  const auto begin = mesh_index_.begin() + first;
  const auto end = begin + count;
  Eigen::AlignedBox3d box, centre_box;
  for (auto it = begin; it != end; ++it) {
    for (const Vec3& p : by_mesh_index[static_cast<std::size_t>(*it)])
      box.extend(p);
    centre_box.extend(centroids[static_cast<std::size_t>(*it)]);
  }
  Node& filled = nodes_[static_cast<std::size_t>(node)];
  filled.centre = box.center();
  filled.half = box.sizes() / 2;
  if (count <= kLeafTriangles) {
    filled.first = first;
    filled.count = count;
    return;
  }
  int axis = 0;
  centre_box.sizes().maxCoeff(&axis);
  const std::int32_t half_count = count / 2;
  std::nth_element(begin, begin + half_count, end, [&](std::int32_t x, std::int32_t y) {
    return centroids[static_cast<std::size_t>(x)](axis) <
           centroids[static_cast<std::size_t>(y)](axis);
  });
  const auto left = static_cast<std::int32_t>(nodes_.size());
  filled.first = left;
  filled.count = 0;
  nodes_.emplace_back();
  nodes_.emplace_back();
  build(left, first, half_count, by_mesh_index, centroids);
  build(left + 1, first + half_count, count - half_count, by_mesh_index, centroids);
}

MeshPair closest_pair(const MeshBvh& store_s, const geometry::Transform& T_p_s,
                      const MeshBvh& aircraft_p) {
  ClosestVisitor visitor{};
  visitor.best.closest.distance = std::numeric_limits<double>::infinity();
  DualTraversal<ClosestVisitor>(store_s, T_p_s, aircraft_p, visitor).run();
  return visitor.best;
}

// The warm bound is one step above the previous pair's distance at this pose, so that the
// descent still meets and accepts the first pair (in its order) at the minimum, as the cold one
// does: with ties (parallel faces) both return the same pair.
MeshPair closest_pair(const MeshBvh& store_s, const geometry::Transform& T_p_s,
                      const MeshBvh& aircraft_p, TreePair& previous) {
  ClosestVisitor visitor{};
  visitor.best.closest.distance = std::numeric_limits<double>::infinity();
  DualTraversal<ClosestVisitor> traversal(store_s, T_p_s, aircraft_p, visitor);
  MeshPair warm;
  const bool has_warm = previous.store >= 0 && previous.aircraft >= 0;
  if (has_warm) {
    warm = traversal.pair(previous.store, previous.aircraft);
    visitor.best.closest.distance =
        std::nextafter(warm.closest.distance, std::numeric_limits<double>::infinity());
  }
  traversal.run();
  if (visitor.best.store_triangle < 0 && has_warm) {  // rounding kept it out: it is the minimum
    visitor.best = warm;
    visitor.best_in_trees = previous;
  }
  previous = visitor.best_in_trees;
  return visitor.best;
}

void pairs_within(const MeshBvh& store_s, const geometry::Transform& T_p_s,
                  const MeshBvh& aircraft_p, double max_distance_m, std::vector<MeshPair>& out) {
  WithinVisitor visitor{max_distance_m, out};
  DualTraversal<WithinVisitor>(store_s, T_p_s, aircraft_p, visitor).run();
}

geometry::Vec6 distance_jacobian(const Vec3& p_store_p, const Vec3& t_p_s, const Vec3& normal_p) {
  geometry::Vec6 J;
  J.head<3>() = (p_store_p - t_p_s).cross(normal_p);
  J.tail<3>() = normal_p;
  return J;
}

double LeverArmReach::at(double lever_arm_m) const {
  const double by_blocks = u_translation_m + u_rotation_rad * lever_arm_m;
  const double whole2 = lambda_max * (1 + lever_arm_m * lever_arm_m);
  const double by_whole = by_blocks * by_blocks <= whole2 ? by_blocks : std::sqrt(whole2);
  // 1e-9 above the bound: a pair's u, rounded, cannot then exceed it (the filter downstream
  // compares the same quantities and would otherwise lose a pair in the last ulp).
  return base_m + sigmas * std::min(by_blocks, by_whole) * (1 + 1e-9);
}

// The direction bound: with a = p - q (store point minus aircraft point) and a0 = c_s - c_a,
// |a - a0| <= e (the boxes' half diagonals), so the contact normal n = a / |a| is within
// dn = 2 e / |a0| of n0 = a0 / |a0| (a touching pair has |a0| <= e: no narrowing then, its
// normal being the face's). J - J0 = [(p - c_s) x n + (c_s - t) x (n - n0); n - n0] has parts
// of norm at most |h_s| + |c_s - t| dn and dn, and sqrt(J^T C J) is a norm of J:
// u <= u(J0) + u_rotation |dJ_r| + u_translation |dJ_t| (Cauchy-Schwarz on the cross term), or
// u(J0) + sqrt(lambda_max) |dJ|.
double LeverArmReach::at(const Eigen::AlignedBox3d& store_box,
                         const Eigen::AlignedBox3d& aircraft_box) const {
  constexpr double kNoBound = std::numeric_limits<double>::infinity();
  if (cov == nullptr) return kNoBound;
  const Vec3 between = store_box.center() - aircraft_box.center();
  const double centres_m = between.norm();
  const double store_half_m = store_box.sizes().norm() / 2;
  const double e = store_half_m + aircraft_box.sizes().norm() / 2;
  if (!(centres_m > e)) return kNoBound;
  const double dn = 2 * e / centres_m;
  const Vec3 n0 = between / centres_m;
  const geometry::Vec6 J0 = distance_jacobian(store_box.center(), t_p_s, n0);
  const double u0 = std::sqrt(std::max(0.0, J0.dot(*cov * J0)));
  const double d_rotation = store_half_m + (store_box.center() - t_p_s).norm() * dn;
  const double by_blocks = u_rotation_rad * d_rotation + u_translation_m * dn;
  const double by_whole = std::sqrt(lambda_max * (d_rotation * d_rotation + dn * dn));
  // The same relative 1e-9 as at(lever_arm_m), against rounding.
  const double u = (u0 + std::min(by_blocks, by_whole)) * (1 + 1e-9);
  return base_m + sigmas * u;
}

void pairs_within(const MeshBvh& store_s, const geometry::Transform& T_p_s,
                  const MeshBvh& aircraft_p, const LeverArmReach& reach,
                  std::vector<MeshPair>& out) {
  LeverArmWithinVisitor visitor{reach, out};
  DualTraversal<LeverArmWithinVisitor>(store_s, T_p_s, aircraft_p, visitor).run();
}

}  // namespace storetrack::clearance
