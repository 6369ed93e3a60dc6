#include "storetrack/msg/crc.hpp"

#include <array>

namespace storetrack::msg {
namespace {

// Table for the reflected IEEE 802.3 polynomial (ISO 3309 / ITU-T V.42), built at compile time.
constexpr std::array<std::uint32_t, 256> make_crc32_table() {
  std::array<std::uint32_t, 256> table{};
  for (std::uint32_t i = 0; i < 256; ++i) {
    std::uint32_t c = i;
    for (int bit = 0; bit < 8; ++bit)
      c = (c & 1u) ? (c >> 1) ^ 0xEDB88320u : (c >> 1);
    table[i] = c;
  }
  return table;
}
constexpr auto kCrc32Table = make_crc32_table();

}  // namespace

std::uint32_t crc32(std::span<const std::uint8_t> data, std::uint32_t crc) {
  std::uint32_t c = crc ^ 0xFFFFFFFFu;
  for (std::uint8_t b : data)
    c = kCrc32Table[(c ^ b) & 0xFFu] ^ (c >> 8);
  return c ^ 0xFFFFFFFFu;
}

}  // namespace storetrack::msg
