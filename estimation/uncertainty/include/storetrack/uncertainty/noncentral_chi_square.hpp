// The noncentral chi-square's survival function: a chi-square test's detection probability
// against a known shift (docs/calibration-health.md). Defined in statistics.cpp beside the
// central one; a header of its own so that the many users of statistics.hpp do not depend on it.
#pragma once

#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::uncertainty {

/// P(X > x) for X noncentral chi-square with `dof` degrees of freedom and noncentrality lambda
/// (|mean|^2 of the standardised Gaussian). Throws std::invalid_argument unless dof >= 1 and
/// lambda >= 0.
double noncentral_chi_square_survival(double x, DegreesOfFreedom dof, double lambda);

}  // namespace storetrack::uncertainty
