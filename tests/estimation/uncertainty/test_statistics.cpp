// binomial_interval against closed forms and an independent exact computation (Python
// math.comb sums over the probability mass function, values below).
#include <stdexcept>

#include <gtest/gtest.h>

#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::uncertainty {
namespace {

TEST(BinomialInterval, FairCoinTenTrials) {
  // P(X = 0) = P(X = 10) = 1/1024 < 0.001 < P(X <= 1) = 11/1024.
  const CountInterval c = binomial_interval(10, 0.5, 0.001);
  EXPECT_EQ(c.low, 1);
  EXPECT_EQ(c.high, 9);
}

TEST(BinomialInterval, CoverageOfTwoSigmaIntervals) {
  const CountInterval a = binomial_interval(800, 0.954499736, 0.001);
  EXPECT_EQ(a.low, 744);
  EXPECT_EQ(a.high, 780);
  const CountInterval b = binomial_interval(100, 0.954499736, 0.001);
  EXPECT_EQ(b.low, 88);
  EXPECT_EQ(b.high, 100);  // P(X = 100) = 0.0094 > 0.001: all inside is acceptable
}

TEST(BinomialInterval, RejectsBadArguments) {
  EXPECT_THROW(binomial_interval(0, 0.5, 0.001), std::invalid_argument);
  EXPECT_THROW(binomial_interval(10, 1.0, 0.001), std::invalid_argument);
  EXPECT_THROW(binomial_interval(10, 0.5, 0.6), std::invalid_argument);
}

}  // namespace
}  // namespace storetrack::uncertainty
