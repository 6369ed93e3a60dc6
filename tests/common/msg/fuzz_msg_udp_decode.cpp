// libFuzzer target: decode_datagram must reject or accept any input without UB, and whatever
// it accepts must re-encode to the identical datagram (the wire form is canonical).
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>

#include "storetrack/msg/byte_order.hpp"
#include "storetrack/msg/udp_codec.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace storetrack::msg;
  AnyMessage message;
  DatagramHeader header;
  if (decode_datagram(std::span<const std::uint8_t>(data, size), message, &header) !=
      DecodeError::kNone)
    return 0;
  std::uint8_t again[kMaxDatagramBytes];
  const int n = std::visit(
      [&](const auto& m) { return encode_datagram(m, again, header.datagram_seq); }, message);
  if (n != static_cast<int>(size) || std::memcmp(again, data, size) != 0) std::abort();
  return 0;
}
