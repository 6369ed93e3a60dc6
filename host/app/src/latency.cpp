#include "latency.hpp"

#include <algorithm>
#include <bit>
#include <cmath>

namespace storetrack::hostapp {
namespace {

constexpr int kSub = LatencyStats::kSubBucketBits;

// Values below 2^kSub have a bucket each; above, 2^kSub buckets per power of two.
std::size_t bucket_of(std::uint64_t v) {
  if (v < (1u << kSub)) return static_cast<std::size_t>(v);
  const int e = 63 - std::countl_zero(v);  // 2^e <= v < 2^(e+1), e >= kSub
  const std::uint64_t sub = (v >> (e - kSub)) & ((1u << kSub) - 1);
  return (static_cast<std::size_t>(e - kSub + 1) << kSub) + static_cast<std::size_t>(sub);
}

std::uint64_t upper_edge(std::size_t bucket) {
  if (bucket < (1u << kSub)) return bucket;
  const int e = static_cast<int>(bucket >> kSub) + kSub - 1;
  const std::uint64_t sub = bucket & ((1u << kSub) - 1);
  const std::uint64_t lower = (std::uint64_t{1} << e) + (sub << (e - kSub));
  return lower + (std::uint64_t{1} << (e - kSub)) - 1;
}

}  // namespace

void LatencyStats::add(std::int64_t ns) {
  if (ns < 0) {
    ++negative_;
    ns = 0;
  }
  ++buckets_[bucket_of(static_cast<std::uint64_t>(ns))];
  ++count_;
  max_ = std::max(max_, ns);
}

std::int64_t LatencyStats::percentile(double q) const {
  if (count_ == 0) return 0;
  // Nearest-rank definition: the smallest value with at least q of the samples at or below it.
  const auto rank = static_cast<std::uint64_t>(
      std::clamp(std::ceil(q * static_cast<double>(count_)), 1.0, static_cast<double>(count_)));
  std::uint64_t seen = 0;
  for (std::size_t b = 0; b < kBuckets; ++b) {
    seen += buckets_[b];
    if (seen >= rank) return std::min(static_cast<std::int64_t>(upper_edge(b)), max_);
  }
  return max_;
}

nlohmann::json LatencyStats::to_json() const {
  return {{"count", count()},
          {"p50_us", static_cast<double>(percentile(0.5)) * 1e-3},
          {"p99_us", static_cast<double>(percentile(0.99)) * 1e-3},
          {"max_us", static_cast<double>(max()) * 1e-3},
          {"negative", negative_},
          {"percentile_resolution", "histogram: at most 1/64 above the exact value"}};
}

}  // namespace storetrack::hostapp
