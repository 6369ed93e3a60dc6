// The smoothed trajectory as CSV (storetrack-post --smoothed-csv; docs/post-processing.md,
// "Smoothed trajectory"): one line per exposure of a tracked segment, units in the header.
#pragma once

#include <array>
#include <cstdio>
#include <span>

#include <Eigen/Core>

#include "storetrack/smooth/pose_smoother.hpp"

namespace storetrack::post {

/// The quantities of a line: position, yaw/pitch/roll (pylon axes, Z-Y'-X''), velocity,
/// acceleration, angular rate, angular acceleration; names with units.
inline constexpr int kSmoothedOutputs = 18;
extern const std::array<const char*, kSmoothedOutputs> kSmoothedNames;
using SmoothedOutputMap = Eigen::Matrix<double, kSmoothedOutputs, smooth::kStateSize>;

/// The quantities' values at `s` and the map M from the state's perturbation (attitude through
/// d(ypr)/d(rotation), the rest directly): their covariance is M C M^T, loadings M E.
void smoothed_outputs(const smooth::SmoothedState& s, std::array<double, kSmoothedOutputs>& value,
                      SmoothedOutputMap& M);

/// Writes the header and the states to `f` (opened as a new file by the caller); returns false
/// on a write error.
bool write_smoothed_csv(std::FILE* f, std::span<const smooth::SmoothedState> states);

}  // namespace storetrack::post
