// The smoothed trajectory as CSV (storetrack-post --smoothed-csv; docs/post-processing.md,
// "Smoothed trajectory"): one line per exposure of a tracked segment, units in the header.
#pragma once

#include <cstdio>
#include <span>

#include "storetrack/smooth/pose_smoother.hpp"

namespace storetrack::post {

/// Writes the header and the states to `f` (opened as a new file by the caller); returns false
/// on a write error.
bool write_smoothed_csv(std::FILE* f, std::span<const smooth::SmoothedState> states);

}  // namespace storetrack::post
