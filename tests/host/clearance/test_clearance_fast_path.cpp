// The clearance's fast path against an independent brute force (docs/clearance.md, "Speed"):
// along a trajectory of a store under the pylon whose closest feature switches (one tail fin to
// the other as the store rolls through level, the fins past the pylon's aft end), the
// warm-started descent and the per-node feature-switch reach give the exact minimum over all
// triangle pairs, that pair's own closest points and feature, its u, and exactly the candidate
// pairs that the brute force finds within the feature-switch rule; a sample's result does not
// depend on the samples before it. The brute force assembles each pair's distance from all 15
// feature pairs itself; triangle_distance, which skips edge pairs that cannot win, must agree
// with it on every pair bit for bit.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <set>
#include <vector>

#include "storetrack/clearance/clearance.hpp"
#include "synthetic_meshes.hpp"

namespace storetrack::clearance {
namespace {

using geometry::Mat6;
using geometry::Transform;
using geometry::Vec3;
using geometry::Vec6;

// Every triangle pair of the meshes is tested at every pose (~29 000 pairs): under ASan/UBSan
// a few poses keep it a smoke run; the full form is the whole trajectory.
#ifdef STORETRACK_SANITIZE
constexpr int kPoses = 6;
#else
constexpr int kPoses = 48;
#endif

/// Posed as R q + t, the rounding the trees pose with (so distances compare bit for bit).
Triangle triangle_of(const TriangleMesh& m, std::size_t i, const Transform& T) {
  const auto& t = m.triangles[i];
  const auto pose = [&](std::int32_t v) {
    return Vec3(T.linear() * m.vertices[static_cast<std::size_t>(v)] + T.translation());
  };
  return {pose(t[0]), pose(t[1]), pose(t[2])};
}

/// The store rolls from +0.3 to -0.3 rad (through level, where the two upper fins trade places
/// as the closest), moves aft until its fins leave the pylon box, and drops slowly.
Transform trajectory(int i) {
  const double s = (i + 0.37) / kPoses;  // never exactly level (the two fins would tie)
  return geometry::make_transform({0.3 - 0.6 * s, 0.05 * std::sin(5 * s), 0.1 * s},
                                  {-0.5 + 0.9 * s, 0.05 * std::sin(3 * s), 0.45 + 0.1 * s});
}

/// Alternating covariances of the pose: rotation-dominated with a correlation, and
/// translation-dominated (the two bounds of the feature-switch reach each win on one).
Mat6 covariance(int i) {
  Vec6 sigma;
  if (i % 2 == 0)
    sigma << 2e-3, 1.5e-3, 1e-3, 0.5e-3, 0.5e-3, 0.8e-3;
  else
    sigma << 0.2e-3, 0.2e-3, 0.3e-3, 3e-3, 2e-3, 2.5e-3;
  Mat6 C = sigma.array().square().matrix().asDiagonal();
  C(0, 4) = C(4, 0) = 0.5 * sigma(0) * sigma(4);
  C(2, 3) = C(3, 2) = -0.3 * sigma(2) * sigma(3);
  return C;
}

/// Every one of the 15 feature pairs of two triangles (6 vertex-face, 9 edge-edge), from the
/// public primitives, none skipped, in triangle_distance's order; then the crossing test.
ClosestPair every_feature_pair(const Triangle& a, const Triangle& b) {
  ClosestPair best;
  double best2 = std::numeric_limits<double>::infinity();
  const auto consider = [&](const Vec3& pa, const Vec3& pb, Feature f) {
    if ((pa - pb).squaredNorm() < best2) {
      best2 = (pa - pb).squaredNorm();
      best = {0.0, pa, pb, f};
    }
  };
  for (const Vec3& v : a)
    consider(v, closest_point_on_triangle(v, b), Feature::kVertexFace);
  for (const Vec3& v : b)
    consider(closest_point_on_triangle(v, a), v, Feature::kFaceVertex);
  for (std::size_t i = 0; i < 3; ++i)
    for (std::size_t j = 0; j < 3; ++j) {
      Vec3 on_a, on_b;
      closest_points_of_segments(a[i], a[(i + 1) % 3], b[j], b[(j + 1) % 3], on_a, on_b);
      consider(on_a, on_b, Feature::kEdgeEdge);
    }
  best.distance = std::sqrt(best2);
  Vec3 x;
  for (std::size_t i = 0; i < 3 && best.distance > 0; ++i)
    if (segment_crosses_triangle(a[i], a[(i + 1) % 3], b, x) ||
        segment_crosses_triangle(b[i], b[(i + 1) % 3], a, x))
      best = {0.0, x, x, Feature::kPenetration};
  if (best.distance == 0 && best.feature != Feature::kPenetration)
    best.feature = Feature::kPenetration;
  return best;
}

struct BruteForce {
  ClosestPair best;
  std::size_t store = 0, aircraft = 0;
  std::vector<ClosestPair> all;  ///< [store * aircraft triangles + aircraft]
  int primitive_differs = 0;     ///< pairs where triangle_distance is not every_feature_pair
};

BruteForce brute_force(const TriangleMesh& store, const Transform& T, const TriangleMesh& air) {
  BruteForce b;
  b.best.distance = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < store.triangles.size(); ++i) {
    const Triangle a = triangle_of(store, i, T);
    for (std::size_t j = 0; j < air.triangles.size(); ++j) {
      const Triangle t = triangle_of(air, j, Transform::Identity());
      b.all.push_back(every_feature_pair(a, t));
      const ClosestPair fast = triangle_distance(a, t);
      b.primitive_differs += fast.distance != b.all.back().distance ||
                             fast.p_a != b.all.back().p_a || fast.p_b != b.all.back().p_b ||
                             fast.feature != b.all.back().feature;
      if (b.all.back().distance < b.best.distance) {
        b.best = b.all.back();
        b.store = i;
        b.aircraft = j;
      }
    }
  }
  return b;
}

double pair_u(const ClosestPair& c, const Vec3& t, const Mat6& C) {
  const Vec6 J = distance_jacobian(c.p_a, t, (c.p_a - c.p_b) / c.distance);
  return std::sqrt(J.dot(C * J));
}

/// What a trajectory exercised (a check that it does what it is for).
struct Exercised {
  std::set<std::int32_t> closest_store_triangles;
  std::set<Feature> features;
  int feature_switch_samples = 0, ties = 0, most_candidates = 0;
};

/// One sample of `warm` (the model that has seen the samples before) against the brute force:
/// the minimum, its pair's points, feature and u, the cold descent's pair, exactly the candidate
/// pairs of the feature-switch rule, and a fresh model's bound bit for bit.
void expect_brute_force_result(const TriangleMesh& store, const TriangleMesh& air,
                               const Transform& T, const Mat6& C, ClearanceModel& warm, int i,
                               Exercised& seen) {
  const MeshBvh store_tree(store), air_tree(air);
  const BruteForce truth = brute_force(store, T, air);
  ASSERT_GT(truth.best.distance, 0) << i;  // the trajectories never touch
  EXPECT_EQ(truth.primitive_differs, 0) << i;
  const PartClearance r = warm.evaluate(T, C).front();

  // The minimum, and the points and feature of a pair that attains it (ties between
  // neighbouring triangles sharing the closest vertex or edge are the same points).
  EXPECT_EQ(r.distance_m, truth.best.distance) << i;
  const ClosestPair& own =
      truth.all[static_cast<std::size_t>(r.store_triangle) * air.triangles.size() +
                static_cast<std::size_t>(r.aircraft_triangle)];
  EXPECT_EQ(own.distance, truth.best.distance) << i;
  EXPECT_EQ(r.p_store_p, own.p_a) << i;
  EXPECT_EQ(r.p_aircraft_p, own.p_b) << i;
  EXPECT_EQ(r.feature, own.feature) << i;
  seen.ties += r.store_triangle != static_cast<std::int32_t>(truth.store) ||
               r.aircraft_triangle != static_cast<std::int32_t>(truth.aircraft);
  // The plain (cold) descent picks the very same pair.
  const MeshPair plain = closest_pair(store_tree, T, air_tree);
  EXPECT_EQ(plain.store_triangle, r.store_triangle) << i;
  EXPECT_EQ(plain.aircraft_triangle, r.aircraft_triangle) << i;
  EXPECT_EQ(plain.closest.p_a, r.p_store_p) << i;
  EXPECT_EQ(plain.closest.p_b, r.p_aircraft_p) << i;
  EXPECT_EQ(plain.closest.feature, r.feature) << i;
  const double u = pair_u(own, T.translation(), C);
  EXPECT_NEAR(r.u_distance_m, u, 1e-15) << i;

  // The feature-switch rule over every pair: d - 4 u < d_min - 2 u_min.
  const double single = r.distance_m - kCoverageFactor * r.u_distance_m;
  int candidates = 0;
  for (const ClosestPair& c : truth.all)
    candidates += c.distance - kCandidateReachSigmas * pair_u(c, T.translation(), C) < single;
  EXPECT_EQ(r.candidate_pairs, std::max(1, candidates)) << i;

  // No memory of the samples before: a fresh model gives the same bound bit for bit.
  ClearanceModel cold({{"store", BodyFrame::kStore, store}, {"aircraft", BodyFrame::kPylon, air}});
  const PartClearance c = cold.evaluate(T, C).front();
  EXPECT_EQ(c.lower_bound_m, r.lower_bound_m) << i;
  EXPECT_EQ(c.features, r.features) << i;
  EXPECT_EQ(c.store_triangle, r.store_triangle) << i;

  seen.closest_store_triangles.insert(r.store_triangle);
  seen.features.insert(r.feature);
  seen.feature_switch_samples += r.features > 1;
  seen.most_candidates = std::max(seen.most_candidates, candidates);
}

TEST(ClearanceFastPath, AgreesWithTheBruteForceAlongAFeatureSwitchingTrajectory) {
  const TriangleMesh store = test::store(3.0, 0.2, 12, 12);
  const TriangleMesh air = test::aircraft(6, 6, 0.6);
  ClearanceModel warm({{"store", BodyFrame::kStore, store}, {"aircraft", BodyFrame::kPylon, air}});
  Exercised seen;
  for (int i = 0; i < kPoses; ++i)
    expect_brute_force_result(store, air, trajectory(i), covariance(i), warm, i, seen);
  // The trajectory does what it is for: the closest feature changes along it.
  EXPECT_GE(seen.closest_store_triangles.size(), 2U);
#ifndef STORETRACK_SANITIZE
  EXPECT_GE(seen.features.size(), 2U);
#endif
  RecordProperty("closest_store_triangles", static_cast<int>(seen.closest_store_triangles.size()));
  RecordProperty("feature_switch_samples", seen.feature_switch_samples);
  RecordProperty("tied_minimum_pairs", seen.ties);
  std::printf("closest store triangles %zu, features %zu, samples with > 1 feature %d, ties %d\n",
              seen.closest_store_triangles.size(), seen.features.size(),
              seen.feature_switch_samples, seen.ties);
}

// The released store falling past the adjacent store, metres away, the two nearly parallel,
// pitching and yawing a little, with the large rotation uncertainty of a distant store: many
// pairs along the two bodies near the minimum and within the feature-switch reach, the case the
// leaves' gap along the line through two triangles' centroids prunes for (docs/clearance.md,
// "Distance"). The same assertions as above.
TEST(ClearanceFastPath, AgreesWithTheBruteForceBesideAParallelStoreFarAway) {
  const TriangleMesh store = test::store(3.0, 0.2, 12, 12);
  const TriangleMesh adjacent =
      test::posed(store, geometry::make_transform({0, 0, 0}, {-0.2, 0.7, 0.0}));
  ClearanceModel warm(
      {{"store", BodyFrame::kStore, store}, {"aircraft", BodyFrame::kPylon, adjacent}});
  Vec6 sigma;
  sigma << 2e-3, 1.9e-3, 1.5e-3, 2e-3, 1.5e-3, 1.2e-3;
  Mat6 C = sigma.array().square().matrix().asDiagonal();
  C(1, 5) = C(5, 1) = 0.4 * sigma(1) * sigma(5);
  Exercised seen;
  const int poses = std::max(4, kPoses / 4);
  for (int i = 0; i < poses; ++i) {
    const double s = (i + 0.41) / poses;
    const Transform T = geometry::make_transform(
        {0.02 * std::sin(4 * s), 0.03 * s, 0.015 * std::cos(3 * s)}, {0.1 * s, 0.0, 0.6 + 2 * s});
    expect_brute_force_result(store, adjacent, T, C, warm, i, seen);
  }
  EXPECT_GE(seen.most_candidates, 10);  // a reach that holds many pairs
  std::printf("most candidate pairs %d, samples with > 1 feature %d\n", seen.most_candidates,
              seen.feature_switch_samples);
}

// A jump (not a continuous trajectory): the warm start from a far pair still gives the minimum.
TEST(ClearanceFastPath, AJumpBetweenSamplesStillGivesTheMinimum) {
  const TriangleMesh store = test::store(3.0, 0.2, 12, 12);
  const TriangleMesh air = test::aircraft(6, 6, 0.6);
  ClearanceModel warm({{"store", BodyFrame::kStore, store}, {"aircraft", BodyFrame::kPylon, air}});
  const Mat6 C = covariance(0);
  for (const int i : {0, kPoses - 1, kPoses / 2, 1}) {
    const Transform T = trajectory(i);
    EXPECT_EQ(warm.evaluate(T, C).front().distance_m, brute_force(store, T, air).best.distance)
        << i;
  }
}

}  // namespace
}  // namespace storetrack::clearance
