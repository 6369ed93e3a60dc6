// The outlier gate of every calibration fit (docs/calibration.md, "Method", step 4).
#pragma once

#include <vector>

#include <Eigen/Core>

namespace storetrack::calib {

/// used[i][k] for the weighted residuals r[i][k] (view i, point k): rejected when |r|^2 exceeds
/// the chi-square (2 dof) quantile at 1 - false_alarm / N times a robust residual variance
/// (1.4826 x the median absolute residual component, so outliers do not widen the gate).
/// false_alarm <= 0 keeps every point.
std::vector<std::vector<char>> outlier_gate(const std::vector<std::vector<Eigen::Vector2d>>& r,
                                            double false_alarm);

}  // namespace storetrack::calib
