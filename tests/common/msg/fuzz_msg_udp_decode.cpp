// libFuzzer target: decode_datagram must reject or accept any input without UB, and whatever
// it accepts must re-encode to the identical datagram (the wire form is canonical).
// Input byte 0 selects the mode: odd = the harness rewrites the CRC-32 trailer first, so that
// the fuzzer also reaches the header, length and payload range checks behind the CRC.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>

#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/msg/crc.hpp"
#include "storetrack/msg/udp_codec.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace storetrack::msg;
  if (size == 0) return 0;
  static std::uint8_t buffer[kMaxDatagramBytes + 64];
  const std::size_t n = std::min(size - 1, sizeof(buffer));
  std::memcpy(buffer, data + 1, n);
  const std::span<std::uint8_t> datagram(buffer, n);
  if ((data[0] & 1) != 0 && n >= kUdpCrcBytes) {
    storetrack::bytes::BigEndianWriter w(datagram.subspan(n - kUdpCrcBytes));
    w.put_u32(crc32(datagram.first(n - kUdpCrcBytes)));
  }
  AnyMessage message;
  DatagramHeader header;
  if (decode_datagram(datagram, message, &header) != DecodeError::kNone) return 0;
  std::uint8_t again[kMaxDatagramBytes];
  const int encoded = std::visit(
      [&](const auto& m) { return encode_datagram(m, again, header.datagram_seq); }, message);
  if (encoded != static_cast<int>(n) || std::memcmp(again, buffer, n) != 0) std::abort();
  return 0;
}
