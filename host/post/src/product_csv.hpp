// The store-separation data product as CSV (storetrack-post --product-csv; docs/post-processing.md,
// "Data product"): one line per smoothed exposure, time since the release t0, units in the
// header, each quantity with u (k = 1), U (k = 2) and u's noise and shared parts.
#pragma once

#include <cstdio>
#include <span>

#include "storetrack/smooth/release_time.hpp"
#include "storetrack/smooth/store_product.hpp"

namespace storetrack::post {

/// Writes the header and the samples to `f` (opened as a new file by the caller); returns false
/// on a write error.
bool write_product_csv(std::FILE* f, std::span<const smooth::ProductSample> samples,
                       const smooth::ReleaseTime& release);

}  // namespace storetrack::post
