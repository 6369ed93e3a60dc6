// Triangle meshes of the clearance bodies and their checks on load (docs/clearance.md, "Files").
//
// read_stl() reads binary and ASCII STL; every refusal is a MeshError naming the file and, where
// there is one, the triangle (0-based, in file order): a non-finite vertex, a degenerate
// (zero-area) triangle, a binary file shorter or longer than its triangle count states, ASCII that
// does not follow the facet/outer loop/vertex grammar.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "storetrack/geometry/transform.hpp"

namespace storetrack::clearance {

/// A refused mesh: what() is "<file>: triangle <i>: <reason>" or "<file>: <reason>".
class MeshError : public std::runtime_error {
 public:
  MeshError(std::string file, std::optional<std::int64_t> triangle, std::string reason);
  const std::string& file() const noexcept { return file_; }
  std::optional<std::int64_t> triangle() const noexcept { return triangle_; }
  const std::string& reason() const noexcept { return reason_; }

 private:
  std::string file_;
  std::optional<std::int64_t> triangle_;
  std::string reason_;
};

/// Indexed triangles. Vertices of the file that are bit-identical are one vertex (STL has no
/// indices), which is what the closedness check counts edges on.
struct TriangleMesh {
  std::vector<geometry::Vec3> vertices;
  std::vector<std::array<std::int32_t, 3>> triangles;
  std::string source;  ///< the file it came from (for messages)
};

/// A triangle is degenerate when twice its area is at most this times its longest edge squared:
/// its height is then within a few float32 rounding steps (2^-23 relative) of zero, so the file
/// cannot tell it from a line. STL stores float32, and CAD exports write ASCII at that precision.
inline constexpr double kDegenerateHeightRatio = 8.0 * 1.1920928955078125e-07;

/// Reads an STL file (binary or ASCII; told apart by the binary size rule, see the .cpp).
/// Coordinates are as in the file (units are the geometry file's business). Throws MeshError,
/// or jsonfile::FileReadError when the file cannot be read.
TriangleMesh read_stl(const std::string& path);
/// The same from bytes already in memory; `file` names them in messages.
TriangleMesh parse_stl(const std::string& bytes, const std::string& file);

/// Refuses (MeshError) a mesh that is not closed: every edge must be shared by exactly two
/// triangles. Names the first triangle with an edge that is not.
void check_closed(const TriangleMesh& mesh);

/// Axis-aligned extent of the mesh (largest side of its bounding box), in the mesh's units.
double largest_extent(const TriangleMesh& mesh);

/// Scales (units to metres) and moves (into the frame a of T_a_m) every vertex in place.
void transform_mesh(TriangleMesh& mesh, double scale_to_m, const geometry::Transform& T_a_m);

}  // namespace storetrack::clearance
