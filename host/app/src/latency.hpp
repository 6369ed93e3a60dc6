// Latency statistics (nanoseconds): exact percentiles over all samples kept.
#pragma once

#include <cstdint>
#include <vector>

#include <nlohmann/json.hpp>

namespace storetrack::hostapp {

class LatencyStats {
 public:
  void add(std::int64_t ns) { samples_.push_back(ns); }
  std::size_t count() const { return samples_.size(); }
  /// q in [0, 1]; 0 when empty.
  std::int64_t percentile(double q) const;
  std::int64_t max() const;
  nlohmann::json to_json() const;

 private:
  std::vector<std::int64_t> samples_;
};

}  // namespace storetrack::hostapp
