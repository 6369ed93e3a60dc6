#include <algorithm>
#include <bit>
#include <cmath>
#include <map>
#include <sstream>
#include <utility>

#include "mesh_build.hpp"
#include "storetrack/clearance/mesh.hpp"

namespace storetrack::clearance {
namespace {

using geometry::Vec3;

std::string point_text(const Vec3& p) {
  std::ostringstream s;
  s.precision(9);
  s << "(" << p.x() << ", " << p.y() << ", " << p.z() << ")";
  return s.str();
}

}  // namespace

MeshBuilder::MeshBuilder(std::string file) {
  mesh_.source = std::move(file);
}

std::size_t MeshBuilder::KeyHash::operator()(const Key& k) const noexcept {
  std::uint64_t h = k.x * 0x9E3779B97F4A7C15ull;
  h ^= k.y + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2);
  h ^= k.z + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2);
  return static_cast<std::size_t>(h);
}

std::int32_t MeshBuilder::vertex_index(const Vec3& p) {
  // + 0.0 turns -0.0 into +0.0, so that the two zeros are one vertex.
  const Key key{std::bit_cast<std::uint64_t>(p.x() + 0.0),
                std::bit_cast<std::uint64_t>(p.y() + 0.0),
                std::bit_cast<std::uint64_t>(p.z() + 0.0)};
  const auto [it, added] = index_.emplace(key, static_cast<std::int32_t>(mesh_.vertices.size()));
  if (added) mesh_.vertices.push_back(p);
  return it->second;
}

void MeshBuilder::add(const std::array<Vec3, 3>& v) {
  for (int i = 0; i < 3; ++i)
    if (!v[static_cast<std::size_t>(i)].allFinite())
      throw MeshError(mesh_.source, size(),
                      "vertex " + std::to_string(i) + " is not finite " +
                          point_text(v[static_cast<std::size_t>(i)]));
  const Vec3 e0 = v[1] - v[0], e1 = v[2] - v[1], e2 = v[0] - v[2];
  const double longest2 = std::max({e0.squaredNorm(), e1.squaredNorm(), e2.squaredNorm()});
  const double twice_area = e0.cross(-e2).norm();
  if (!(twice_area > kDegenerateHeightRatio * longest2))
    throw MeshError(mesh_.source, size(),
                    "degenerate (zero-area) triangle " + point_text(v[0]) + " " + point_text(v[1]) +
                        " " + point_text(v[2]));
  if (mesh_.triangles.size() >= static_cast<std::size_t>(INT32_MAX / 3))
    throw MeshError(mesh_.source, size(), "too many triangles");
  mesh_.triangles.push_back({vertex_index(v[0]), vertex_index(v[1]), vertex_index(v[2])});
}

TriangleMesh MeshBuilder::finish() {
  if (mesh_.triangles.empty()) throw MeshError(mesh_.source, std::nullopt, "no triangles");
  index_.clear();
  return std::move(mesh_);
}

void check_closed(const TriangleMesh& mesh) {
  // Undirected edge -> (number of triangles using it, first such triangle).
  std::map<std::pair<std::int32_t, std::int32_t>, std::pair<int, std::int64_t>> edges;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& tri = mesh.triangles[t];
    for (int k = 0; k < 3; ++k) {
      const std::int32_t a = tri[static_cast<std::size_t>(k)];
      const std::int32_t b = tri[static_cast<std::size_t>((k + 1) % 3)];
      auto& entry = edges[{std::min(a, b), std::max(a, b)}];
      if (entry.first++ == 0) entry.second = static_cast<std::int64_t>(t);
    }
  }
  for (const auto& [edge, use] : edges) {
    if (use.first == 2) continue;
    throw MeshError(mesh.source, use.second,
                    "mesh must be closed, but its edge " +
                        point_text(mesh.vertices[static_cast<std::size_t>(edge.first)]) + "-" +
                        point_text(mesh.vertices[static_cast<std::size_t>(edge.second)]) +
                        " is shared by " + std::to_string(use.first) +
                        " triangle(s), not 2 (a hole, a crack or a non-manifold edge)");
  }
}

double largest_extent(const TriangleMesh& mesh) {
  Eigen::AlignedBox3d box;
  for (const Vec3& p : mesh.vertices)
    box.extend(p);
  return box.isEmpty() ? 0.0 : box.sizes().maxCoeff();
}

void transform_mesh(TriangleMesh& mesh, double scale_to_m, const geometry::Transform& T_a_m) {
  for (Vec3& p : mesh.vertices)
    p = T_a_m * (scale_to_m * p);
}

}  // namespace storetrack::clearance
