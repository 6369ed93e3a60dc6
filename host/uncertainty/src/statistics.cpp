#include "storetrack/uncertainty/statistics.hpp"

#include <stdexcept>

#include <boost/math/distributions/chi_squared.hpp>

namespace storetrack::uncertainty {

double chi_square_quantile(double probability, double dof) {
  if (!(probability > 0 && probability < 1) || !(dof > 0))
    throw std::invalid_argument("chi_square_quantile: need 0 < probability < 1 and dof > 0");
  return boost::math::quantile(boost::math::chi_squared_distribution<double>(dof), probability);
}

double chi_square_survival(double x, double dof) {
  if (!(dof > 0)) throw std::invalid_argument("chi_square_survival: dof must be > 0");
  if (!(x > 0)) return 1.0;
  return boost::math::cdf(
      boost::math::complement(boost::math::chi_squared_distribution<double>(dof), x));
}

}  // namespace storetrack::uncertainty
