// LatencyStats keeps fixed memory over a run of any length (it used to keep every sample: one
// entry per exposure for ever) and its percentiles stay within the stated resolution of the
// exact nearest-rank values computed here independently from the sorted samples.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include "latency.hpp"
#include "storetrack/testing/counting_allocator.hpp"

namespace storetrack::hostapp {
namespace {

TEST(LatencyStats, MemoryIsFixedOverAMillionExposures) {
  auto stats = std::make_unique<LatencyStats>();
  const long before = storetrack::testing::allocation_count();
  for (int i = 0; i < 1'000'000; ++i)
    stats->add(100'000 + (i % 5000) * 37);
  EXPECT_EQ(storetrack::testing::allocation_count() - before, 0)
      << "add() allocated: memory grows with the run";
  EXPECT_EQ(stats->count(), 1'000'000u);
  EXPECT_LE(sizeof(LatencyStats), 32u * 1024u);
}

TEST(LatencyStats, PercentilesWithinOneSixtyFourthAboveTheExactValue) {
  std::mt19937_64 rng(11);
  std::lognormal_distribution<double> d(std::log(300e3), 0.8);  // ~300 us, long tail
  LatencyStats stats;
  std::vector<std::int64_t> all;
  for (int i = 0; i < 200'000; ++i) {
    const auto v = static_cast<std::int64_t>(d(rng));
    all.push_back(v);
    stats.add(v);
  }
  std::sort(all.begin(), all.end());
  for (double q : {0.0, 0.01, 0.5, 0.9, 0.99, 0.999, 1.0}) {
    const std::size_t rank =
        std::max<std::size_t>(1, static_cast<std::size_t>(std::ceil(q * all.size())));
    const std::int64_t exact = all[rank - 1];
    const std::int64_t got = stats.percentile(q);
    EXPECT_GE(got, exact) << "q " << q;
    EXPECT_LE(static_cast<double>(got), static_cast<double>(exact) * (1.0 + 1.0 / 64)) << "q " << q;
  }
  EXPECT_EQ(stats.max(), all.back());
  // Small values are exact; negative ones (a clock step) are counted and kept as 0.
  LatencyStats small;
  for (int v : {5, 3, 9, -4})
    small.add(v);
  EXPECT_EQ(small.percentile(0.5), 3);
  EXPECT_EQ(small.percentile(1.0), 9);
  EXPECT_EQ(small.percentile(0.25), 0);
  EXPECT_EQ(small.negative(), 1u);
  EXPECT_EQ(LatencyStats{}.percentile(0.99), 0);
}

}  // namespace
}  // namespace storetrack::hostapp
