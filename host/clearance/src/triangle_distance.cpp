#include "storetrack/clearance/triangle_distance.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace storetrack::clearance {

using geometry::Vec3;

const char* feature_name(Feature f) {
  switch (f) {
    case Feature::kVertexFace:
      return "store vertex - aircraft face";
    case Feature::kFaceVertex:
      return "store face - aircraft vertex";
    case Feature::kEdgeEdge:
      return "edge - edge";
    case Feature::kPenetration:
      return "penetration";
  }
  return "?";
}

Vec3 closest_point_on_triangle(const Vec3& p, const Triangle& t) {
  const Vec3& a = t[0];
  const Vec3& b = t[1];
  const Vec3& c = t[2];
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + (d1 / (d1 - d3)) * ab;
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + (d2 / (d2 - d6)) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
  const double denom = 1.0 / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

void closest_points_of_segments(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1,
                                Vec3& on_p, Vec3& on_q) {
  const Vec3 d1 = p1 - p0, d2 = q1 - q0, r = p0 - q0;
  const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
  double s = 0, t = 0;
  if (a <= 0 && e <= 0) {
    on_p = p0;
    on_q = q0;
    return;
  }
  if (a <= 0) {
    t = std::clamp(f / e, 0.0, 1.0);
  } else {
    const double c = d1.dot(r);
    if (e <= 0) {
      s = std::clamp(-c / a, 0.0, 1.0);
    } else {
      const double b = d1.dot(d2);
      const double denom = a * e - b * b;
      s = denom > 0 ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
      t = (b * s + f) / e;
      if (t < 0) {
        t = 0;
        s = std::clamp(-c / a, 0.0, 1.0);
      } else if (t > 1) {
        t = 1;
        s = std::clamp((b - c) / a, 0.0, 1.0);
      }
    }
  }
  on_p = p0 + s * d1;
  on_q = q0 + t * d2;
}

namespace {

/// segment_crosses_triangle with t's normal n (unnormalised) and the ends' sides s0 = n.(p0 -
/// t0), s1 = n.(p1 - t0) given: triangle_distance computes them once per triangle, not per edge.
bool crosses_with_sides(const Vec3& p0, const Vec3& p1, double s0, double s1, const Triangle& t,
                        const Vec3& n, Vec3& crossing) {
  if (!((s0 < 0 && s1 > 0) || (s0 > 0 && s1 < 0))) return false;
  const Vec3 x = p0 + (s0 / (s0 - s1)) * (p1 - p0);
  // Inside (boundary included) when x is on the inner side of all three edges.
  for (int k = 0; k < 3; ++k) {
    const Vec3& u = t[static_cast<std::size_t>(k)];
    const Vec3& v = t[static_cast<std::size_t>((k + 1) % 3)];
    if ((v - u).cross(x - u).dot(n) < 0) return false;
  }
  crossing = x;
  return true;
}

/// The sides of triangle e's vertices against the plane of t (normal n = (t1 - t0) x (t2 - t0)).
std::array<double, 3> sides(const Triangle& e, const Triangle& t, const Vec3& n) {
  return {n.dot(e[0] - t[0]), n.dot(e[1] - t[0]), n.dot(e[2] - t[0])};
}

}  // namespace

bool segment_crosses_triangle(const Vec3& p0, const Vec3& p1, const Triangle& t, Vec3& crossing) {
  const Vec3 n = (t[1] - t[0]).cross(t[2] - t[0]);
  return crosses_with_sides(p0, p1, n.dot(p0 - t[0]), n.dot(p1 - t[0]), t, n, crossing);
}

ClosestPair triangle_distance(const Triangle& a, const Triangle& b) {
  ClosestPair best;
  double best2 = std::numeric_limits<double>::infinity();
  const auto consider = [&](const Vec3& pa, const Vec3& pb, Feature f) {
    const double d2 = (pa - pb).squaredNorm();
    if (d2 < best2) {
      best2 = d2;
      best.p_a = pa;
      best.p_b = pb;
      best.feature = f;
    }
  };
  for (const Vec3& v : a)
    consider(v, closest_point_on_triangle(v, b), Feature::kVertexFace);
  for (const Vec3& v : b)
    consider(closest_point_on_triangle(v, a), v, Feature::kFaceVertex);
  Vec3 on_a, on_b;
  for (std::size_t i = 0; i < 3; ++i) {
    const Vec3 &a0 = a[i], &a1 = a[(i + 1) % 3];
    for (std::size_t j = 0; j < 3; ++j) {
      const Vec3 &b0 = b[j], &b1 = b[(j + 1) % 3];
      // The edges' boxes apart by more than the best so far: they cannot improve it. Spare: a
      // relative 1e-9 and 1e-20 m^2 (the rounding of points of ~10 m coordinates, 1e-15 m,
      // moves d^2 by 2e-15 d), so that rounding never skips a pair the exact test would take.
      const Vec3 gap =
          (a0.cwiseMin(a1) - b0.cwiseMax(b1)).cwiseMax(b0.cwiseMin(b1) - a0.cwiseMax(a1));
      if (gap.cwiseMax(0.0).squaredNorm() > best2 * (1 + 1e-9) + 1e-20) continue;
      closest_points_of_segments(a0, a1, b0, b1, on_a, on_b);
      consider(on_a, on_b, Feature::kEdgeEdge);
    }
  }
  best.distance = std::sqrt(best2);
  if (best.distance == 0) {  // touching counts as penetration: no clearance is left
    best.feature = Feature::kPenetration;
    return best;
  }
  // Not touching at a feature: they intersect only if an edge of one crosses the other (the
  // same tests as segment_crosses_triangle, each plane and side computed once).
  const Vec3 n_a = (a[1] - a[0]).cross(a[2] - a[0]), n_b = (b[1] - b[0]).cross(b[2] - b[0]);
  const std::array<double, 3> a_sides = sides(a, b, n_b), b_sides = sides(b, a, n_a);
  Vec3 x;
  for (std::size_t i = 0; i < 3; ++i) {
    const std::size_t next = (i + 1) % 3;
    const bool crossed = crosses_with_sides(a[i], a[next], a_sides[i], a_sides[next], b, n_b, x) ||
                         crosses_with_sides(b[i], b[next], b_sides[i], b_sides[next], a, n_a, x);
    if (crossed) {
      best = {0.0, x, x, Feature::kPenetration};
      return best;
    }
  }
  return best;
}

}  // namespace storetrack::clearance
