// Typed decode errors shared by the UDP and CAN FD framings (docs/icd.md "Error handling").
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>

namespace storetrack::msg {

enum class DecodeError : std::uint8_t {
  kNone = 0,
  kTooShort,     ///< fewer bytes than a header + trailer
  kBadMagic,     ///< not a storetrack datagram / frame (magic, CAN channel or frame format)
  kBadVersion,   ///< framing or message version this decoder does not speak
  kBadLength,    ///< length field, payload size or fragment layout inconsistent
  kBadCrc,       ///< CRC-32 mismatch: corrupted in transit
  kUnknownType,  ///< message id not in the schema
  kOutOfRange,   ///< a field value outside its documented range (e.g. mark_count > 64)
};
inline constexpr std::size_t kNumDecodeErrors = 8;

const char* to_string(DecodeError e);

/// Per-error counters for a receiver (one per socket/link): bad input is counted, never fatal.
struct DecodeCounters {
  std::array<std::uint64_t, kNumDecodeErrors> by_error{};  ///< index = DecodeError value

  void record(DecodeError e) { ++by_error[static_cast<std::size_t>(e)]; }
  std::uint64_t count(DecodeError e) const { return by_error[static_cast<std::size_t>(e)]; }
  std::uint64_t ok() const { return count(DecodeError::kNone); }
  std::uint64_t errors() const {
    std::uint64_t n = 0;
    for (std::size_t i = 1; i < kNumDecodeErrors; ++i)
      n += by_error[i];
    return n;
  }
};

}  // namespace storetrack::msg
