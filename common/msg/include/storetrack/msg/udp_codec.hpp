// UDP framing (docs/icd.md "UDP framing"): one datagram per message,
//   header (12 bytes) | payload (schema, big-endian) | CRC-32 (4 bytes, over header + payload).
// Encoders and decoders allocate nothing and never throw (firmware per-frame path); decoders
// trust nothing: every failure is a typed DecodeError, never UB.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <span>
#include <variant>

#include "storetrack/msg/decode_error.hpp"
#include "storetrack/msg/messages.hpp"

namespace storetrack::msg {

inline constexpr std::uint16_t kUdpMagic = 0x5354;  ///< "ST"
inline constexpr std::uint8_t kUdpFramingVersion = 1;
inline constexpr std::size_t kUdpHeaderBytes = 12;
inline constexpr std::size_t kUdpCrcBytes = 4;
inline constexpr std::size_t kMaxDatagramBytes =
    kUdpHeaderBytes + std::max(kMarkObservationsMaxPayloadBytes, kUnitHealthMaxPayloadBytes) +
    kUdpCrcBytes;
static_assert(kMaxDatagramBytes == 12 + 546 + 4, "wire layout size");
static_assert(kMaxDatagramBytes <= 1472,
              "one datagram must fit an Ethernet MTU without IP fragments");

/// The datagram header as decoded (byte offsets in docs/icd.md).
struct DatagramHeader {
  std::uint16_t magic = kUdpMagic;                    ///< offset 0
  std::uint8_t framing_version = kUdpFramingVersion;  ///< offset 2
  std::uint8_t message_id = 0;                        ///< offset 3, MessageId
  std::uint8_t message_version = 0;                   ///< offset 4, schema version of the message
  std::uint8_t unit_id = 0;                           ///< offset 5, sender unit (= payload unit_id)
  std::uint16_t length = 0;        ///< offset 6, whole datagram incl. header + CRC
  std::uint32_t datagram_seq = 0;  ///< offset 8, per-sender counter (loss detection)
};

const char* to_string(DecodeError e);

/// Encodes one datagram into `out`. Returns the datagram size in bytes, -ENOSPC when `out` is
/// too small, -ERANGE when a value cannot be carried (mark_count > 64, a mark coordinate
/// outside -0.5..2047.49 px or NaN). `datagram_seq` is the sender's datagram counter.
int encode_datagram(const MarkObservations& m, std::span<std::uint8_t> out,
                    std::uint32_t datagram_seq = 0);
int encode_datagram(const UnitHealth& m, std::span<std::uint8_t> out,
                    std::uint32_t datagram_seq = 0);

using AnyMessage = std::variant<MarkObservations, UnitHealth>;

/// Decodes one datagram. On kNone `out` holds the message; `header`, when given, holds the
/// header as read once the magic matched (also on a later error: it names a refused version);
/// on error `out` is unspecified. Checks in order: size, magic, framing version,
/// length field, CRC, message id, message version, payload length and value ranges
/// (mark_count <= 64, clock_state, mark coordinates, header unit_id == payload unit_id).
DecodeError decode_datagram(std::span<const std::uint8_t> in, AnyMessage& out,
                            DatagramHeader* header = nullptr);

}  // namespace storetrack::msg
