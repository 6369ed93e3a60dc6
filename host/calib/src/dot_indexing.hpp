// Internals of dot-grid detection: the dots one image gave the centroider, and their indexing
// into the grid model (ring-dot markers, dot_indexing.cpp).
#pragma once

#include <array>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "storetrack/calib/dot_grid_detection.hpp"

namespace storetrack::calib::dots {

struct MeasuredDot {
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();
  double sigma_px = 0;
  bool ring = false;  ///< a donut: its centre is background
};

/// A dot placed on the grid model: node (col, row).
struct IndexedDot {
  int dot = 0;  ///< index into the image's MeasuredDot list
  int col = 0, row = 0;
};

struct GridIndexing {
  std::string failure;  ///< non-empty: the image cannot be indexed, and why
  std::vector<IndexedDot> indexed;
  std::vector<std::pair<int, std::string>> unindexed;  ///< dot index, reason
  std::array<Eigen::Vector2d, 3> markers{};            ///< origin, x marker, y marker
};

/// Indexes `dots` from their three ring dots (origin, x marker, y marker of `board`).
GridIndexing index_ring_dot_grid(const std::vector<MeasuredDot>& dots, const DotGridSpec& board);

}  // namespace storetrack::calib::dots
