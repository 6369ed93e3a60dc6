#include "storetrack/uncertainty/statistics.hpp"

#include <stdexcept>

#include <boost/math/distributions/chi_squared.hpp>

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

}  // namespace storetrack::uncertainty
