// Saturating nanosecond arithmetic: time values from the wire (or from a caller) can sit anywhere
// in the int64 range, and signed overflow is undefined behaviour. Sums and differences clamp to
// INT64_MIN..INT64_MAX instead, so a comparison against a bound still gives the right verdict.
#pragma once

#include <cstdint>
#include <limits>

namespace storetrack::time {

/// a + b clamped to the int64 range.
constexpr std::int64_t saturating_add_ns(std::int64_t a, std::int64_t b) {
  std::int64_t r = 0;
  if (!__builtin_add_overflow(a, b, &r)) return r;
  return b > 0 ? std::numeric_limits<std::int64_t>::max()
               : std::numeric_limits<std::int64_t>::min();
}

/// a - b clamped to the int64 range.
constexpr std::int64_t saturating_sub_ns(std::int64_t a, std::int64_t b) {
  std::int64_t r = 0;
  if (!__builtin_sub_overflow(a, b, &r)) return r;
  return b < 0 ? std::numeric_limits<std::int64_t>::max()
               : std::numeric_limits<std::int64_t>::min();
}

}  // namespace storetrack::time
