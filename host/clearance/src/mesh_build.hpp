// Internal: collects the triangles of a file one at a time, refuses non-finite and degenerate
// ones by index, and merges bit-identical vertices.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <unordered_map>

#include "storetrack/clearance/mesh.hpp"

namespace storetrack::clearance {

class MeshBuilder {
 public:
  explicit MeshBuilder(std::string file);
  /// Throws MeshError naming triangle size() when `v` has a non-finite coordinate or is
  /// degenerate (kDegenerateHeightRatio).
  void add(const std::array<geometry::Vec3, 3>& v);
  std::int64_t size() const { return static_cast<std::int64_t>(mesh_.triangles.size()); }
  TriangleMesh finish();

 private:
  struct Key {
    std::uint64_t x, y, z;
    bool operator==(const Key&) const = default;
  };
  struct KeyHash {
    std::size_t operator()(const Key& k) const noexcept;
  };
  std::int32_t vertex_index(const geometry::Vec3& p);

  TriangleMesh mesh_;
  std::unordered_map<Key, std::int32_t, KeyHash> index_;
};

}  // namespace storetrack::clearance
