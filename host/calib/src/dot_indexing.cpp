// Ring-dot grid indexing (docs/calibration.md, "Dot grids"). First the dot lattice is grown
// without the markers: from a ring dot and its two nearest non-collinear neighbours (a square
// lattice's nearest neighbours are along its axes under any perspective: a diagonal is longer
// than both axis steps), node by node, each free node next to a found one predicted by the
// homography of the found nodes around it and taking the nearest dot within kMatchTolerance
// spacings. That gives every reached dot integer lattice coordinates up to one of the square
// lattice's 8 symmetries. The three ring dots then fix that symmetry exactly, in integers:
// origin -> x marker must be (origin_to_x - 1, 0) and origin -> y marker (0, origin_to_y - 1)
// after it; the symmetry's handedness says whether the print is seen from the front.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>

#include <Eigen/Dense>

#include "dot_indexing.hpp"
#include "zhang_initialisation.hpp"

namespace storetrack::calib::dots {
namespace {

/// A dot is on a node when within this fraction of the local spacing of its prediction (a
/// dot's neighbours are 1 spacing away, so half of it is the most a nearest search can take;
/// 0.3 leaves room for the local homography's error under lens distortion).
constexpr double kMatchTolerance = 0.3;
/// Nodes within this many steps (Chebyshev) of a free node predict it (a local homography:
/// lens distortion bends the lattice over the whole image, not over a few spacings).
constexpr int kLocalRadius = 3;

using Node = std::pair<int, int>;     // lattice (i, j) while growing; grid (col, row) after
using Lattice = std::map<Node, int>;  // node -> dot index

std::string node_text(double col, double row) {
  std::ostringstream s;
  s.precision(3);
  s << "(" << col << ", " << row << ")";
  return s.str();
}

/// Homography lattice -> image of the found nodes within `radius` of `centre` (all if radius
/// < 0); the affine map of three nodes when there are only three.
Eigen::Matrix3d local_map(const std::vector<MeasuredDot>& dots, const Lattice& found,
                          const Node& centre, int radius) {
  std::vector<Observation> points;
  for (const auto& [node, dot] : found) {
    if (radius >= 0 && (std::abs(node.first - centre.first) > radius ||
                        std::abs(node.second - centre.second) > radius))
      continue;
    Observation o;
    o.p_board = Eigen::Vector3d(node.first, node.second, 0);
    o.pixel = dots[static_cast<size_t>(dot)].pixel;
    points.push_back(o);
  }
  if (points.size() == 3) {  // exact affine map through the three
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero(), P = Eigen::Matrix3d::Zero();
    for (int k = 0; k < 3; ++k) {
      A.col(k) = Eigen::Vector3d(points[k].p_board.x(), points[k].p_board.y(), 1);
      P.col(k) = points[k].pixel.homogeneous();
    }
    return P * A.inverse();
  }
  BoardView view;
  for (const Observation& o : points)
    view.points.push_back(&o);
  return board_homography(view);
}

Eigen::Vector2d apply(const Eigen::Matrix3d& H, double i, double j) {
  return (H * Eigen::Vector3d(i, j, 1)).hnormalized();
}

/// The map predicting `node` from the found nodes near it: local when they are enough and
/// spread over two directions, else wider, else all.
Eigen::Matrix3d predictor(const std::vector<MeasuredDot>& dots, const Lattice& found,
                          const Node& node) {
  if (found.size() <= 4) return local_map(dots, found, node, -1);
  for (int radius = kLocalRadius; radius <= 4 * kLocalRadius; radius *= 2) {
    int n = 0, imin = 1 << 30, imax = -(1 << 30), jmin = 1 << 30, jmax = -(1 << 30);
    for (const auto& [m, dot] : found)
      if (std::abs(m.first - node.first) <= radius && std::abs(m.second - node.second) <= radius) {
        ++n;
        imin = std::min(imin, m.first), imax = std::max(imax, m.first);
        jmin = std::min(jmin, m.second), jmax = std::max(jmax, m.second);
      }
    if (n >= 6 && imax > imin && jmax > jmin) return local_map(dots, found, node, radius);
  }
  return local_map(dots, found, node, -1);
}

/// One growth pass: every free node next to a found one takes the nearest free dot within
/// tolerance of its prediction, unless another node claims the same dot. Returns nodes added.
int grow_once(const std::vector<MeasuredDot>& dots, Lattice& found, std::vector<bool>& taken) {
  std::map<Node, bool> frontier;
  for (const auto& [node, dot] : found)
    for (int dj = -1; dj <= 1; ++dj)
      for (int di = -1; di <= 1; ++di) {
        const Node n{node.first + di, node.second + dj};
        if (!found.count(n)) frontier[n] = true;
      }
  std::map<int, std::vector<Node>> claims;
  for (const auto& [n, unused] : frontier) {
    const Eigen::Matrix3d H = predictor(dots, found, n);
    const Eigen::Vector2d p = apply(H, n.first, n.second);
    const double spacing = std::min((apply(H, n.first + 1, n.second) - p).norm(),
                                    (apply(H, n.first, n.second + 1) - p).norm());
    int nearest = -1;
    double nearest_d = kMatchTolerance * spacing;
    for (size_t k = 0; k < dots.size(); ++k) {
      const double d = (dots[k].pixel - p).norm();
      if (!taken[k] && d < nearest_d) {
        nearest_d = d;
        nearest = static_cast<int>(k);
      }
    }
    if (nearest >= 0) claims[nearest].push_back(n);
  }
  int added = 0;
  for (const auto& [dot, nodes] : claims) {
    if (nodes.size() != 1) continue;  // one dot near two nodes' predictions: not taken
    found[nodes[0]] = dot;
    taken[static_cast<size_t>(dot)] = true;
    ++added;
  }
  return added;
}

/// The lattice reached from dot `seed` (its coordinates: seed (0, 0), its nearest neighbour
/// (1, 0), its nearest neighbour off that line (0, 1)).
Lattice grow_lattice(const std::vector<MeasuredDot>& dots, int seed) {
  Lattice found{{{0, 0}, seed}};
  std::vector<bool> taken(dots.size(), false);
  taken[static_cast<size_t>(seed)] = true;
  const Eigen::Vector2d s = dots[static_cast<size_t>(seed)].pixel;
  std::vector<int> by_distance;
  for (size_t k = 0; k < dots.size(); ++k)
    if (static_cast<int>(k) != seed) by_distance.push_back(static_cast<int>(k));
  std::sort(by_distance.begin(), by_distance.end(), [&](int a, int b) {
    return (dots[static_cast<size_t>(a)].pixel - s).norm() <
           (dots[static_cast<size_t>(b)].pixel - s).norm();
  });
  if (by_distance.size() < 2) return found;
  int first = by_distance[0];
  const Eigen::Vector2d a = (dots[static_cast<size_t>(first)].pixel - s).normalized();
  int second = -1;
  for (size_t k = 1; k < by_distance.size() && second < 0; ++k) {
    const Eigen::Vector2d b = (dots[static_cast<size_t>(by_distance[k])].pixel - s).normalized();
    if (std::abs(a.dot(b)) < std::cos(M_PI / 6)) second = by_distance[k];  // > 30 deg apart
  }
  if (second < 0) return found;
  // (i, j) in the image's handedness (x right, y down), which the naming below relies on.
  Eigen::Matrix2d basis;
  basis << dots[static_cast<size_t>(first)].pixel - s, dots[static_cast<size_t>(second)].pixel - s;
  if (basis.determinant() < 0) std::swap(first, second);
  found[{1, 0}] = first;
  found[{0, 1}] = second;
  taken[static_cast<size_t>(first)] = taken[static_cast<size_t>(second)] = true;
  while (grow_once(dots, found, taken) > 0) {
  }
  return found;
}

/// A symmetry of the square lattice: (i, j) -> S (i, j), S a signed permutation matrix.
std::vector<Eigen::Matrix2i> lattice_symmetries() {
  std::vector<Eigen::Matrix2i> out;
  for (int swap = 0; swap < 2; ++swap)
    for (int sx : {-1, 1})
      for (int sy : {-1, 1}) {
        Eigen::Matrix2i S = Eigen::Matrix2i::Zero();
        if (swap) {
          S(0, 1) = sx, S(1, 0) = sy;
        } else {
          S(0, 0) = sx, S(1, 1) = sy;
        }
        out.push_back(S);
      }
  return out;
}

struct Naming {
  std::array<int, 3> ring{};  // positions in the rings list: origin, x marker, y marker
  Eigen::Matrix2i S = Eigen::Matrix2i::Identity();
};

}  // namespace

GridIndexing index_ring_dot_grid(const std::vector<MeasuredDot>& dots, const DotGridSpec& board) {
  GridIndexing out;
  std::vector<int> rings;
  for (size_t k = 0; k < dots.size(); ++k)
    if (dots[k].ring) rings.push_back(static_cast<int>(k));
  if (rings.size() != 3) {
    out.failure = rings.empty() ? std::string("no ring (marker) dots found")
                                : "found " + std::to_string(rings.size()) +
                                      " ring (marker) dots, need exactly 3 (origin, x, y marker)";
    return out;
  }
  const Lattice lattice = grow_lattice(dots, rings[0]);
  std::map<int, Node> node_of;
  for (const auto& [node, dot] : lattice)
    node_of[dot] = node;
  std::array<Eigen::Vector2i, 3> m;
  for (int k = 0; k < 3; ++k) {
    if (!node_of.count(rings[static_cast<size_t>(k)])) {
      const Eigen::Vector2d p = dots[static_cast<size_t>(rings[static_cast<size_t>(k)])].pixel;
      char at[64];
      std::snprintf(at, sizeof at, "(%.1f, %.1f)", p.x(), p.y());
      out.failure = "the ring dot at " + std::string(at) +
                    " px is not connected to the others through the dot lattice (" +
                    std::to_string(lattice.size()) + " dots reached)";
      return out;
    }
    const Node n = node_of[rings[static_cast<size_t>(k)]];
    m[static_cast<size_t>(k)] = {n.first, n.second};
  }
  // Every naming of the rings and lattice symmetry that puts them where the model says.
  const Eigen::Vector2i to_x(board.origin_to_x_marker - 1, 0),
      to_y(0, board.origin_to_y_marker - 1);
  std::vector<Naming> front, mirrored;
  std::array<int, 3> perm{0, 1, 2};
  do {
    for (const Eigen::Matrix2i& S : lattice_symmetries()) {
      if (S * (m[perm[1]] - m[perm[0]]) != to_x || S * (m[perm[2]] - m[perm[0]]) != to_y) continue;
      // The lattice's (i, j) follow the image's handedness (x right, y down); the print's
      // mathematical axes seen from the front are the opposite one.
      (S.determinant() < 0 ? front : mirrored).push_back({perm, S});
    }
  } while (std::next_permutation(perm.begin(), perm.end()));
  if (front.empty()) {
    const Eigen::Vector2i d1 = m[1] - m[0], d2 = m[2] - m[0];
    out.failure = mirrored.empty()
                      ? "the 3 ring dots do not fit the grid model: on the dot lattice they are "
                        "at steps " +
                            node_text(d1.x(), d1.y()) + " and " + node_text(d2.x(), d2.y()) +
                            " from one another; the model needs " +
                            std::to_string(board.origin_to_x_marker - 1) + " along x and " +
                            std::to_string(board.origin_to_y_marker - 1) +
                            " along y from the origin (check --origin-to-x, --origin-to-y)"
                      : "ring dots mirrored: the y marker is clockwise from the x marker; the "
                        "board is seen from behind or printed mirrored";
    return out;
  }
  if (front.size() > 1) {
    out.failure = "ambiguous ring dots: " + std::to_string(front.size()) +
                  " namings of origin / x / y fit the model";
    return out;
  }
  const Naming& naming = front[0];
  for (int k = 0; k < 3; ++k)
    out.markers[static_cast<size_t>(k)] =
        dots[static_cast<size_t>(rings[static_cast<size_t>(naming.ring[static_cast<size_t>(k)])])]
            .pixel;
  const Eigen::Vector2i origin = m[naming.ring[0]];
  const std::string model = std::to_string(board.cols) + "x" + std::to_string(board.rows);
  for (size_t k = 0; k < dots.size(); ++k) {
    if (!node_of.count(static_cast<int>(k))) {
      out.unindexed.emplace_back(static_cast<int>(k),
                                 "off the dot lattice (not within 0.3 spacings of a node "
                                 "reached from the markers)");
      continue;
    }
    const Node n = node_of[static_cast<int>(k)];
    const Eigen::Vector2i g = Eigen::Vector2i(board.origin_col, board.origin_row) +
                              naming.S * (Eigen::Vector2i(n.first, n.second) - origin);
    if (g.x() < 0 || g.y() < 0 || g.x() >= board.cols || g.y() >= board.rows) {
      out.unindexed.emplace_back(
          static_cast<int>(k),
          "outside the " + model + " grid model (grid node " + node_text(g.x(), g.y()) + ")");
      continue;
    }
    out.indexed.push_back({static_cast<int>(k), g.x(), g.y()});
  }
  return out;
}

}  // namespace storetrack::calib::dots
