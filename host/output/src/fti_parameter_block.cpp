#include "storetrack/output/fti_parameter_block.hpp"

#include <cerrno>

#include "storetrack/bytes/byte_cursor.hpp"

namespace storetrack::output {
namespace {

// The block_version field alone, read before anything else so that a block of another layout
// is refused by its version, not as a short block (version 1 was 4 bytes shorter).
bool read_block_version(std::span<const std::uint8_t> in, std::uint16_t& version) {
  bytes::BigEndianReader r(in);
  r.skip(kFtiParameterBlockVersionOffset);
  version = r.get_u16();
  return r.ok();
}

}  // namespace

int encode_fti_parameter_block(const msg::FtiSample& s, std::span<std::uint8_t> out) {
  bytes::BigEndianWriter w(out);
  if (msg::pack_payload(s, w) != 0) return -ENOSPC;  // no FtiSample value is out of range
  return static_cast<int>(w.size());
}

int decode_fti_parameter_block(std::span<const std::uint8_t> in, msg::FtiSample& s) {
  std::uint16_t version = 0;
  if (!read_block_version(in, version)) return -EINVAL;
  if (version != kFtiParameterBlockVersion) return -EPROTO;
  if (in.size() < kFtiParameterBlockBytes) return -EINVAL;
  bytes::BigEndianReader r(in.first(kFtiParameterBlockBytes));
  return msg::unpack_payload(r, s) == msg::DecodeError::kNone ? 0 : -EINVAL;
}

std::string fti_parameter_block_error(std::span<const std::uint8_t> in) {
  std::uint16_t version = 0;
  if (!read_block_version(in, version))
    return "FTI parameter block of " + std::to_string(in.size()) +
           " bytes: too short to hold its version (offset 18)";
  if (version != kFtiParameterBlockVersion)
    return "FTI parameter block version " + std::to_string(version) +
           ": this reader decodes only version " + std::to_string(kFtiParameterBlockVersion) +
           " (" + std::to_string(kFtiParameterBlockBytes) + " bytes, docs/fti-output.md)";
  if (in.size() < kFtiParameterBlockBytes)
    return "FTI parameter block version " + std::to_string(version) + " of " +
           std::to_string(in.size()) + " bytes: needs " + std::to_string(kFtiParameterBlockBytes);
  return {};
}

}  // namespace storetrack::output
