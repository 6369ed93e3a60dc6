// 8-bit PNG encoding (libpng) of grey or RGB pixels, for the simulator's board images and the
// unit's snapshot. Without libpng in the build it encodes nothing: the callers write PGM.
#pragma once

#include <cstdint>
#include <cstdio>
#include <optional>

namespace storetrack::png {

enum class Channels { kGray = 1, kRgb = 3 };

/// Whether this build encodes PNG (libpng found when it was configured).
bool available();

/// Encodes `height` rows of `width` pixels, each `channels` bytes (rows packed, top first), as
/// an 8-bit PNG into `fp`. `compression_level`: zlib's 0..9, libpng's default when absent.
/// Returns false when libpng fails (what stands in `fp` is then incomplete) or !available().
bool write_png(std::FILE* fp, const std::uint8_t* pixels, int width, int height, Channels channels,
               std::optional<int> compression_level = std::nullopt);

}  // namespace storetrack::png
