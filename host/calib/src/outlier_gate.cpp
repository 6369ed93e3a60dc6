#include "outlier_gate.hpp"

#include <algorithm>
#include <cmath>

#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::calib {

std::vector<std::vector<char>> outlier_gate(const std::vector<std::vector<Eigen::Vector2d>>& r,
                                            double false_alarm) {
  std::vector<std::vector<char>> used(r.size());
  std::vector<double> components;
  for (size_t i = 0; i < r.size(); ++i) {
    used[i].assign(r[i].size(), 1);
    for (const auto& e : r[i]) {
      components.push_back(std::abs(e.x()));
      components.push_back(std::abs(e.y()));
    }
  }
  if (!(false_alarm > 0) || components.empty()) return used;
  const auto mid = components.begin() + static_cast<std::ptrdiff_t>(components.size() / 2);
  std::nth_element(components.begin(), mid, components.end());
  const double robust_sigma = 1.4826 * *mid;
  const auto points = static_cast<double>(components.size() / 2);
  const double gate = uncertainty::chi_square_quantile(
      uncertainty::Probability(1 - false_alarm / points), uncertainty::DegreesOfFreedom(2));
  for (size_t i = 0; i < r.size(); ++i)
    for (size_t k = 0; k < r[i].size(); ++k)
      used[i][k] = r[i][k].squaredNorm() <= gate * robust_sigma * robust_sigma;
  return used;
}

}  // namespace storetrack::calib
