#include "latency.hpp"

#include <algorithm>
#include <cmath>

namespace storetrack::hostapp {

std::int64_t LatencyStats::percentile(double q) const {
  if (samples_.empty()) return 0;
  std::vector<std::int64_t> s = samples_;
  // Nearest-rank definition: the smallest value with at least q of the samples at or below it.
  const auto rank =
      static_cast<std::size_t>(std::max(1.0, std::ceil(q * static_cast<double>(s.size()))));
  std::nth_element(s.begin(), s.begin() + static_cast<std::ptrdiff_t>(rank - 1), s.end());
  return s[rank - 1];
}

std::int64_t LatencyStats::max() const {
  return samples_.empty() ? 0 : *std::max_element(samples_.begin(), samples_.end());
}

nlohmann::json LatencyStats::to_json() const {
  return {{"count", count()},
          {"p50_us", static_cast<double>(percentile(0.5)) * 1e-3},
          {"p99_us", static_cast<double>(percentile(0.99)) * 1e-3},
          {"max_us", static_cast<double>(max()) * 1e-3}};
}

}  // namespace storetrack::hostapp
