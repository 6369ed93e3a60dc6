// Latency statistics (nanoseconds) in fixed memory: a log-linear histogram (64 sub-buckets per
// power of two), so a run of any length keeps 29 KiB and never allocates after construction.
// Percentiles are the UPPER edge of the nearest-rank sample's bucket: never below the exact
// nearest-rank value and at most 1/64 (1.6 %) above it. Count and max are exact.
#pragma once

#include <array>
#include <cstdint>

#include <nlohmann/json.hpp>

namespace storetrack::hostapp {

class LatencyStats {
 public:
  static constexpr int kSubBucketBits = 6;  // 64 sub-buckets: relative resolution 1/64
  static constexpr std::size_t kBuckets = (63 - kSubBucketBits + 1) << kSubBucketBits;

  void add(std::int64_t ns);
  std::size_t count() const { return static_cast<std::size_t>(count_); }
  /// q in [0, 1]; 0 when empty.
  std::int64_t percentile(double q) const;
  std::int64_t max() const { return max_; }
  /// Negative inputs (a clock step) are counted here and recorded as 0.
  std::uint64_t negative() const { return negative_; }
  nlohmann::json to_json() const;

 private:
  std::array<std::uint64_t, kBuckets> buckets_{};
  std::uint64_t count_ = 0, negative_ = 0;
  std::int64_t max_ = 0;
};

}  // namespace storetrack::hostapp
