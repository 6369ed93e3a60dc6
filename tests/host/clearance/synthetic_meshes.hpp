// Meshes with known geometry for the clearance tests and benchmark (header-only): a UV sphere,
// boxes, a fin (a thin triangular prism), a plane patch, a store (body of revolution with four
// fins) and an aircraft (wing lower surface with a pylon), and STL writers (binary and ASCII).
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <numbers>
#include <string>
#include <vector>

#include "storetrack/clearance/mesh.hpp"
#include "storetrack/geometry/transform.hpp"

namespace storetrack::test {

using clearance::TriangleMesh;
using geometry::Vec3;

/// Appends a triangle by its corners (vertices not shared: the mesh is read back through STL
/// files, or the tests only need the triangles).
inline void add_triangle(TriangleMesh& m, const Vec3& a, const Vec3& b, const Vec3& c) {
  const auto base = static_cast<std::int32_t>(m.vertices.size());
  m.vertices.insert(m.vertices.end(), {a, b, c});
  m.triangles.push_back({base, base + 1, base + 2});
}

inline void add_quad(TriangleMesh& m, const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  add_triangle(m, a, b, c);
  add_triangle(m, a, c, d);
}

/// UV sphere: `rings` latitude bands (poles are vertices, on -z and +z), `segments` longitudes.
inline TriangleMesh uv_sphere(const Vec3& centre, double radius, int rings, int segments) {
  TriangleMesh m;
  const auto at = [&](int i, int j) {
    if (i == 0) return Vec3(centre - radius * Vec3::UnitZ());  // poles: one vertex each
    if (i == rings) return Vec3(centre + radius * Vec3::UnitZ());
    const double polar = std::numbers::pi * i / rings;  // 0 at -z
    const double az = 2 * std::numbers::pi * (j % segments) / segments;
    return Vec3(centre + radius * Vec3(std::sin(polar) * std::cos(az),
                                       std::sin(polar) * std::sin(az), -std::cos(polar)));
  };
  for (int i = 0; i < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      const Vec3 a = at(i, j), b = at(i, j + 1), c = at(i + 1, j + 1), d = at(i + 1, j);
      if (i == 0)
        add_triangle(m, a, c, d);
      else if (i == rings - 1)
        add_triangle(m, a, b, d);
      else
        add_quad(m, a, b, c, d);
    }
  return m;
}

/// Box with half sides `half` about `centre`, 12 triangles.
inline TriangleMesh box(const Vec3& centre, const Vec3& half) {
  TriangleMesh m;
  const auto v = [&](int sx, int sy, int sz) {
    return Vec3(centre + Vec3(sx * half.x(), sy * half.y(), sz * half.z()));
  };
  add_quad(m, v(-1, -1, -1), v(-1, 1, -1), v(1, 1, -1), v(1, -1, -1));
  add_quad(m, v(-1, -1, 1), v(1, -1, 1), v(1, 1, 1), v(-1, 1, 1));
  add_quad(m, v(-1, -1, -1), v(1, -1, -1), v(1, -1, 1), v(-1, -1, 1));
  add_quad(m, v(-1, 1, -1), v(-1, 1, 1), v(1, 1, 1), v(1, 1, -1));
  add_quad(m, v(-1, -1, -1), v(-1, -1, 1), v(-1, 1, 1), v(-1, 1, -1));
  add_quad(m, v(1, -1, -1), v(1, 1, -1), v(1, 1, 1), v(1, -1, 1));
  return m;
}

/// A fin: the planform triangle (root_front, root_back, tip) extruded by +-thickness/2 along
/// `side` (a closed triangular prism, 8 triangles).
inline TriangleMesh fin(const Vec3& root_front, const Vec3& root_back, const Vec3& tip,
                        const Vec3& side, double thickness) {
  TriangleMesh m;
  const Vec3 o = side.normalized() * (thickness / 2);
  const Vec3 a0 = root_front - o, b0 = root_back - o, c0 = tip - o;
  const Vec3 a1 = root_front + o, b1 = root_back + o, c1 = tip + o;
  add_triangle(m, a0, c0, b0);
  add_triangle(m, a1, b1, c1);
  add_quad(m, a0, b0, b1, a1);
  add_quad(m, b0, c0, c1, b1);
  add_quad(m, c0, a0, a1, c1);
  return m;
}

/// Square patch z = z0 over [-half, half]^2 about (cx, cy), n x n cells (open).
inline TriangleMesh plane_patch(double cx, double cy, double z0, double half, int n) {
  TriangleMesh m;
  const double step = 2 * half / n;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const double x0 = cx - half + i * step, y0 = cy - half + j * step;
      add_quad(m, {x0, y0, z0}, {x0 + step, y0, z0}, {x0 + step, y0 + step, z0},
               {x0, y0 + step, z0});
    }
  return m;
}

inline void append(TriangleMesh& to, const TriangleMesh& from) {
  const auto base = static_cast<std::int32_t>(to.vertices.size());
  to.vertices.insert(to.vertices.end(), from.vertices.begin(), from.vertices.end());
  for (auto t : from.triangles)
    to.triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
}

/// A store (x from the nose, z down): ogive nose, cylinder and boattail of length `length` and
/// radius `radius` about the x axis, closed by end caps, with four tail fins. The nose ends and
/// the boattail starts at the given fractions of the length.
/// stations x segments quads; about 2 stations segments + 2 segments + 32 triangles.
inline TriangleMesh store(double length, double radius, int stations, int segments,
                          double nose_fraction = 0.2, double tail_fraction = 0.85) {
  TriangleMesh m;
  const auto r_at = [&](double x) {  // x in [0, length], nose at 0
    const double nose = nose_fraction * length, tail = tail_fraction * length;
    if (x < nose) return radius * std::sqrt(std::max(0.0, 1 - std::pow(1 - x / nose, 2))) + 1e-3;
    if (x > tail) return radius * (1 - 0.3 * (x - tail) / (length - tail));
    return radius;
  };
  const auto at = [&](int i, int j) {
    const double x = length * i / stations;
    const double az = 2 * std::numbers::pi * (j % segments) / segments;
    return Vec3(x, r_at(x) * std::cos(az), r_at(x) * std::sin(az));
  };
  for (int i = 0; i < stations; ++i)
    for (int j = 0; j < segments; ++j)
      add_quad(m, at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
  const Vec3 nose_tip(0, 0, 0), tail_centre(length, 0, 0);
  for (int j = 0; j < segments; ++j) {
    add_triangle(m, nose_tip, at(0, j), at(0, j + 1));
    add_triangle(m, tail_centre, at(stations, j + 1), at(stations, j));
  }
  const double span = 1.2 * radius, root_front = 0.8 * length, root_back = 0.97 * length;
  for (int k = 0; k < 4; ++k) {
    const double az = std::numbers::pi / 4 + k * std::numbers::pi / 2;
    const Vec3 out(0, std::cos(az), std::sin(az)), side(0, -std::sin(az), std::cos(az));
    append(m, fin(Vec3(root_front, 0, 0) + 0.9 * radius * out,
                  Vec3(root_back, 0, 0) + 0.6 * radius * out,
                  Vec3(root_back, 0, 0) + (0.9 * radius + span) * out, side, 0.008));
  }
  return m;
}

/// The aircraft in frame p (z down, the store hangs below the pylon at z >= 0): a gently curved
/// wing lower surface at z = -h_wing over [x0, x1] x [y0, y1] (nx x ny cells) and a pylon box
/// between it and the store's suspension lugs.
inline TriangleMesh aircraft(int nx, int ny, double h_wing) {
  TriangleMesh m;
  const double x0 = -4, x1 = 6, y0 = -5, y1 = 5;
  const auto at = [&](int i, int j) {
    const double x = x0 + (x1 - x0) * i / nx, y = y0 + (y1 - y0) * j / ny;
    return Vec3(x, y, -h_wing - 0.02 * (x - 1) * (x - 1) - 0.01 * y);
  };
  for (int i = 0; i < nx; ++i)
    for (int j = 0; j < ny; ++j)
      add_quad(m, at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
  append(m, box(Vec3(1.0, 0, -h_wing / 2 - 0.05), Vec3(1.5, 0.12, h_wing / 2 - 0.02)));
  return m;
}

/// Transforms vertices (for posing a body in the tests' frame p).
inline TriangleMesh posed(TriangleMesh m, const geometry::Transform& T) {
  for (Vec3& p : m.vertices)
    p = T * p;
  return m;
}

inline std::string stl_binary(const TriangleMesh& m, const char* header = "storetrack test") {
  std::string out(80, '\0');
  std::memcpy(out.data(), header, std::min<std::size_t>(80, std::strlen(header)));
  const auto put_u32 = [&](std::uint32_t v) {
    for (int i = 0; i < 4; ++i)
      out.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
  };
  const auto put_f32 = [&](double x) {
    std::uint32_t bits;
    const float f = static_cast<float>(x);
    std::memcpy(&bits, &f, 4);
    put_u32(bits);
  };
  put_u32(static_cast<std::uint32_t>(m.triangles.size()));
  for (const auto& t : m.triangles) {
    for (int k = 0; k < 3; ++k)
      put_f32(0.0);
    for (const std::int32_t v : t)
      for (int k = 0; k < 3; ++k)
        put_f32(m.vertices[static_cast<std::size_t>(v)](k));
    out.push_back('\0');
    out.push_back('\0');
  }
  return out;
}

inline std::string stl_ascii(const TriangleMesh& m) {
  std::string out = "solid test\n";
  char line[160];
  for (const auto& t : m.triangles) {
    out += "  facet normal 0 0 0\n    outer loop\n";
    for (const std::int32_t v : t) {
      const Vec3& p = m.vertices[static_cast<std::size_t>(v)];
      std::snprintf(line, sizeof line, "      vertex %.17g %.17g %.17g\n", p.x(), p.y(), p.z());
      out += line;
    }
    out += "    endloop\n  endfacet\n";
  }
  return out + "endsolid test\n";
}

inline void write_file(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary) << bytes;
}

}  // namespace storetrack::test
