// storetrack-clearance-bench: per-sample cost of the store-to-aircraft clearance
// (docs/performance.md, "Clearance"). A ~5 000-triangle store (body of revolution with four
// fins) against a ~20 000-triangle aircraft (wing lower surface and pylon), both from the tests'
// header-only generator, posed along a 256-sample separation (drop, pitch and yaw oscillation).
// Trees are built once (not timed). Cases: the minimum distance alone (closest_pair), and the
// whole sample (ClearanceModel::evaluate: distance, uncertainty, feature-switch pass).
#include <cmath>
#include <vector>

#include <benchmark/benchmark.h>

#include "storetrack/clearance/clearance.hpp"
#include "storetrack/clearance/mesh_bvh.hpp"
#include "synthetic_meshes.hpp"

namespace {

using namespace storetrack;
using geometry::Transform;
using geometry::Vec3;

std::vector<Transform> separation(int samples) {
  std::vector<Transform> poses;
  for (int i = 0; i < samples; ++i) {
    const double s = static_cast<double>(i) / samples;
    poses.push_back(geometry::make_transform(
        {0.01 * std::sin(20 * s), 0.05 * std::sin(7 * s), 0.03 * std::sin(11 * s)},
        {-1.0 - 0.4 * s, 0.05 * s, 0.3 + 2.0 * s * s}));
  }
  return poses;
}

const clearance::TriangleMesh& store_mesh() {
  static const clearance::TriangleMesh m = test::store(3.0, 0.2, 78, 32);
  return m;
}
const clearance::TriangleMesh& aircraft_mesh() {
  static const clearance::TriangleMesh m = test::aircraft(100, 100, 0.6);
  return m;
}

void BM_ClosestPair(benchmark::State& state) {
  const clearance::MeshBvh store(store_mesh()), aircraft(aircraft_mesh());
  const std::vector<Transform> poses = separation(256);
  std::size_t i = 0;
  for (auto _ : state) {
    const clearance::MeshPair p =
        clearance::closest_pair(store, poses[i++ % poses.size()], aircraft);
    benchmark::DoNotOptimize(p.closest.distance);
  }
  state.counters["store_triangles"] = static_cast<double>(store_mesh().triangles.size());
  state.counters["aircraft_triangles"] = static_cast<double>(aircraft_mesh().triangles.size());
}
BENCHMARK(BM_ClosestPair)->Unit(benchmark::kMicrosecond);

void BM_ClearanceSample(benchmark::State& state) {
  clearance::ClearanceModel model({{"store", clearance::BodyFrame::kStore, store_mesh()},
                                   {"aircraft", clearance::BodyFrame::kPylon, aircraft_mesh()}});
  const std::vector<Transform> poses = separation(256);
  geometry::Vec6 sigma;
  sigma << 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3;  // 1 mrad, 1 mm
  const geometry::Mat6 C = sigma.array().square().matrix().asDiagonal();
  std::size_t i = 0;
  double pairs = 0, samples = 0;
  for (auto _ : state) {
    const std::vector<clearance::PartClearance> r = model.evaluate(poses[i++ % poses.size()], C);
    benchmark::DoNotOptimize(r.front().lower_bound_m);
    pairs += r.front().candidate_pairs;
    ++samples;
  }
  state.counters["candidate_pairs"] = pairs / samples;
}
BENCHMARK(BM_ClearanceSample)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
