// The acceptance bands of the honesty tests, derived from their sample size (not tuned): the
// count of k = 2 intervals containing the truth is Binomial(n, 95.45 %) for honest intervals, and
// n independent NEES values of dimension d sum to chi-square(d n). alpha 0.001 per side.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::test {

inline constexpr double kCoverageK2 = 0.954499736;  // P(|N(0,1)| <= 2)
inline constexpr double kAlphaPerSide = 0.001;

struct HonestyBounds {
  double coverage_low = 0, coverage_high = 0;  ///< fraction of samples inside their k = 2 interval
  double nees_low = 0, nees_high = 0;          ///< mean NEES
};

/// n independent samples of a d-dimensional quantity.
inline HonestyBounds derived_bounds(std::int64_t n, int d) {
  HonestyBounds b;
  const uncertainty::CountInterval inside =
      uncertainty::binomial_interval(n, kCoverageK2, kAlphaPerSide);
  b.coverage_low = static_cast<double>(inside.low) / static_cast<double>(n);
  b.coverage_high = static_cast<double>(inside.high) / static_cast<double>(n);
  const uncertainty::DegreesOfFreedom dof(d * static_cast<int>(n));
  b.nees_low = uncertainty::chi_square_quantile(uncertainty::Probability(kAlphaPerSide), dof) /
               static_cast<double>(n);
  b.nees_high = uncertainty::chi_square_quantile(uncertainty::Probability(1 - kAlphaPerSide), dof) /
                static_cast<double>(n);
  return b;
}

/// An acceptance band stated by a requirement (e.g. coverage 93-97 %, NEES within 10 %), widened
/// where the sample size cannot resolve it: a reduced run gets the derived band, not a flake.
inline HonestyBounds widened(HonestyBounds required, const HonestyBounds& derived) {
  required.coverage_low = std::min(required.coverage_low, derived.coverage_low);
  required.coverage_high = std::max(required.coverage_high, derived.coverage_high);
  required.nees_low = std::min(required.nees_low, derived.nees_low);
  required.nees_high = std::max(required.nees_high, derived.nees_high);
  return required;
}

}  // namespace storetrack::test
