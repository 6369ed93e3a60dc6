// CRC-32 (IEEE 802.3 / ISO-HDLC: reflected polynomial 0xEDB88320, init and final XOR
// 0xFFFFFFFF; check value crc32("123456789") = 0xCBF43926), table-driven, no allocation.
// Used as the UDP datagram trailer and as the per-exposure CRC of a CAN FD transfer.
#pragma once

#include <cstdint>
#include <span>

namespace storetrack::msg {

/// CRC of `data`; pass a previous result as `crc` to continue over several spans.
std::uint32_t crc32(std::span<const std::uint8_t> data, std::uint32_t crc = 0);

}  // namespace storetrack::msg
