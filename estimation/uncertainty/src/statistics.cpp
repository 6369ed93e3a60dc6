#include "storetrack/uncertainty/statistics.hpp"

#include "storetrack/uncertainty/noncentral_chi_square.hpp"

#include <stdexcept>

#include <boost/math/distributions/binomial.hpp>
#include <boost/math/distributions/chi_squared.hpp>
#include <boost/math/distributions/non_central_chi_squared.hpp>

namespace storetrack::uncertainty {

double chi_square_quantile(Probability p, DegreesOfFreedom dof) {
  if (!(p.value > 0 && p.value < 1) || dof.value < 1)
    throw std::invalid_argument("chi_square_quantile: need 0 < probability < 1 and dof >= 1");
  return boost::math::quantile(boost::math::chi_squared_distribution<double>(dof.value), p.value);
}

double chi_square_survival(double x, DegreesOfFreedom dof) {
  if (dof.value < 1) throw std::invalid_argument("chi_square_survival: dof must be >= 1");
  if (!(x > 0)) return 1.0;
  return boost::math::cdf(
      boost::math::complement(boost::math::chi_squared_distribution<double>(dof.value), x));
}

double noncentral_chi_square_survival(double x, DegreesOfFreedom dof, double lambda) {
  if (dof.value < 1 || !(lambda >= 0))
    throw std::invalid_argument("noncentral_chi_square_survival: need dof >= 1, lambda >= 0");
  if (!(x > 0)) return 1.0;
  if (lambda == 0) return chi_square_survival(x, dof);
  return boost::math::cdf(boost::math::complement(
      boost::math::non_central_chi_squared_distribution<double>(dof.value, lambda), x));
}

CountInterval binomial_interval(std::int64_t trials, double p, double alpha_per_side) {
  if (trials < 1 || !(p > 0 && p < 1) || !(alpha_per_side > 0 && alpha_per_side < 0.5))
    throw std::invalid_argument("binomial_interval: need trials >= 1, 0 < p < 1, 0 < alpha < 0.5");
  const boost::math::binomial_distribution<double> d(static_cast<double>(trials), p);
  CountInterval out{0, trials};
  // Exact cumulative sums (a count of trials): no quantile rounding policy to reason about.
  while (out.low < trials && boost::math::cdf(d, static_cast<double>(out.low)) <= alpha_per_side)
    ++out.low;  // P(X < low + 1) = cdf(low) <= alpha: low + 1 is still acceptable as a bound
  while (out.high > 0 && boost::math::cdf(boost::math::complement(
                             d, static_cast<double>(out.high - 1))) <= alpha_per_side)
    --out.high;  // P(X > high - 1) <= alpha
  return out;
}

}  // namespace storetrack::uncertainty
