// The FTI parameter block: one FtiSample as 148 big-endian bytes. The SAME block is the payload
// of an iNET-X packet and the body of one Chapter 10 Message Data F0 message, so the recorder and
// the telemetry stream decode identically. Byte-by-byte layout: docs/fti-output.md.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>

#include "storetrack/msg/messages.hpp"

namespace storetrack::output {

inline constexpr std::size_t kFtiParameterBlockBytes = 148;
/// Version of the block layout, carried in the block itself (offset 18).
inline constexpr std::uint16_t kFtiParameterBlockVersion = 1;

/// Writes the block; returns the byte count or -ENOSPC when `out` is too small.
int encode_fti_parameter_block(const msg::FtiSample& sample, std::span<std::uint8_t> out);
/// Reads a block back; returns 0, -EINVAL (too short) or -EPROTO (unknown block version).
int decode_fti_parameter_block(std::span<const std::uint8_t> in, msg::FtiSample& sample);

}  // namespace storetrack::output
