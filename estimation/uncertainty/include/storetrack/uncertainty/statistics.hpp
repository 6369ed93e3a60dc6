// Chi-square quantiles and the consistency statistics of JCGM 101 validation runs: coverage of
// k-sigma intervals per axis and NEES (normalised estimation error squared, whose mean equals
// the dimension when the stated covariance is honest).
#pragma once

#include <array>
#include <cmath>
#include <cstdint>

#include <Eigen/Cholesky>
#include <Eigen/Core>

namespace storetrack::uncertainty {

/// A probability in (0, 1). Explicit so that a bare double cannot stand in for it.
struct Probability {
  constexpr explicit Probability(double p) : value(p) {}
  double value;
};

/// Degrees of freedom of a chi-square distribution (>= 1). Explicit, and only from an integer:
/// a probability (a double) cannot be passed where the degrees of freedom are expected.
struct DegreesOfFreedom {
  constexpr explicit DegreesOfFreedom(int dof) : value(dof) {}
  DegreesOfFreedom(double) = delete;
  int value;
};

/// Quantile of the chi-square distribution: q with P(X <= q) = p for `dof` degrees of freedom.
/// Throws std::invalid_argument unless 0 < p < 1 and dof >= 1.
double chi_square_quantile(Probability p, DegreesOfFreedom dof);
/// Survival function P(X > x).
double chi_square_survival(double x, DegreesOfFreedom dof);

/// Acceptance interval of a count X ~ Binomial(trials, p): the largest `low` and smallest `high`
/// with P(X < low) <= alpha_per_side and P(X > high) <= alpha_per_side.
struct CountInterval {
  std::int64_t low = 0, high = 0;
};
CountInterval binomial_interval(std::int64_t trials, double p, double alpha_per_side);

/// Accumulates coverage per axis (|error_i| <= k sqrt(C_ii)) and NEES = e^T C^-1 e.
template <int N>
class ConsistencyAccumulator {
 public:
  explicit ConsistencyAccumulator(double coverage_factor = 2.0) : k_(coverage_factor) {}

  /// Returns false (and counts nothing) when the covariance is not positive definite.
  bool add(const Eigen::Matrix<double, N, 1>& error, const Eigen::Matrix<double, N, N>& cov) {
    const Eigen::LLT<Eigen::Matrix<double, N, N>> llt(cov);
    if (llt.info() != Eigen::Success || !error.allFinite()) return false;
    for (int i = 0; i < N; ++i)
      if (std::abs(error(i)) <= k_ * std::sqrt(cov(i, i))) ++inside_[static_cast<size_t>(i)];
    nees_sum_ += error.dot(llt.solve(error));
    ++count_;
    return true;
  }
  std::int64_t count() const { return count_; }
  double coverage(int axis) const {
    return count_ ? static_cast<double>(inside_[static_cast<size_t>(axis)]) / count_ : 0.0;
  }
  double mean_nees() const { return count_ ? nees_sum_ / count_ : 0.0; }

 private:
  double k_;
  std::array<std::int64_t, N> inside_{};
  double nees_sum_ = 0;
  std::int64_t count_ = 0;
};

}  // namespace storetrack::uncertainty
