// The FTI parameter block: one FtiSample as 166 big-endian bytes. The SAME block is the payload
// of an iNET-X packet and the body of one Chapter 10 Message Data F0 message, so the recorder and
// the telemetry stream decode identically. It is the FtiSample payload generated from
// common/msg/schema/fti_sample.yaml (field order = wire order); layout: docs/fti-output.md.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

#include "storetrack/msg/messages.hpp"

namespace storetrack::output {

inline constexpr std::size_t kFtiParameterBlockBytes = msg::kFtiSampleFixedBytes;
static_assert(kFtiParameterBlockBytes == 166, "the documented block size (docs/fti-output.md)");
/// Version of the block layout, carried in the block itself (offset 18): the schema's message
/// version. Version 2 added u_budget_process at 144 (coverage_factor moved to 148; version 1
/// was 148 bytes); version 3 appended the clearance at 152 (version 2 was 152 bytes).
inline constexpr std::uint16_t kFtiParameterBlockVersion = msg::kFtiSampleVersion;
static_assert(kFtiParameterBlockVersion == 3);
/// Offset of the block_version field: readable in a block of any version.
inline constexpr std::size_t kFtiParameterBlockVersionOffset = msg::kFtiSampleBlockVersionOffset;
static_assert(kFtiParameterBlockVersionOffset == 18);

/// Writes the block; returns the byte count or -ENOSPC when `out` is too small.
int encode_fti_parameter_block(const msg::FtiSample& sample, std::span<std::uint8_t> out);
/// Reads a block back; returns 0, -EINVAL (too short) or -EPROTO (another block version: a
/// version-1 or version-2 block is refused, not misread; fti_parameter_block_error() says which).
int decode_fti_parameter_block(std::span<const std::uint8_t> in, msg::FtiSample& sample);
/// Why decode_fti_parameter_block() refused `in`, naming the versions and sizes; empty when
/// it would decode.
std::string fti_parameter_block_error(std::span<const std::uint8_t> in);

}  // namespace storetrack::output
