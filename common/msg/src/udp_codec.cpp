#include "storetrack/msg/udp_codec.hpp"

#include <cerrno>

#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/msg/crc.hpp"

namespace storetrack::msg {
namespace {

static_assert(sizeof(DatagramHeader::magic) + sizeof(DatagramHeader::framing_version) +
                      sizeof(DatagramHeader::message_id) + sizeof(DatagramHeader::message_version) +
                      sizeof(DatagramHeader::unit_id) + sizeof(DatagramHeader::length) +
                      sizeof(DatagramHeader::datagram_seq) ==
                  kUdpHeaderBytes,
              "wire layout size");

template <typename Message>
int encode(const Message& m, MessageId id, std::uint8_t version, std::span<std::uint8_t> out,
           std::uint32_t datagram_seq) {
  const std::size_t total = kUdpHeaderBytes + payload_size(m) + kUdpCrcBytes;
  if (out.size() < total) return -ENOSPC;
  bytes::BigEndianWriter w(out.first(total));
  w.put_u16(kUdpMagic);
  w.put_u8(kUdpFramingVersion);
  w.put_u8(static_cast<std::uint8_t>(id));
  w.put_u8(version);
  w.put_u8(m.unit_id);
  w.put_u16(static_cast<std::uint16_t>(total));
  w.put_u32(datagram_seq);
  if (const int rc = pack_payload(m, w); rc != 0) return rc;
  w.put_u32(crc32(out.first(w.size())));
  if (!w.ok() || w.size() != total) return -ENOSPC;
  return static_cast<int>(total);
}

template <typename Message>
DecodeError decode_payload(std::span<const std::uint8_t> payload, std::uint8_t header_unit,
                           AnyMessage& out) {
  Message& m = out.emplace<Message>();
  bytes::BigEndianReader r(payload);
  if (const DecodeError e = unpack_payload(r, m); e != DecodeError::kNone) return e;
  if (m.unit_id != header_unit) return DecodeError::kOutOfRange;
  return DecodeError::kNone;
}

}  // namespace

int encode_datagram(const MarkObservations& m, std::span<std::uint8_t> out,
                    std::uint32_t datagram_seq) {
  return encode(m, MessageId::kMarkObservations, kMarkObservationsVersion, out, datagram_seq);
}

int encode_datagram(const UnitHealth& m, std::span<std::uint8_t> out, std::uint32_t datagram_seq) {
  return encode(m, MessageId::kUnitHealth, kUnitHealthVersion, out, datagram_seq);
}

DecodeError decode_datagram(std::span<const std::uint8_t> in, AnyMessage& out,
                            DatagramHeader* header) {
  if (in.size() < kUdpHeaderBytes + kUdpCrcBytes) return DecodeError::kTooShort;
  bytes::BigEndianReader r(in);
  DatagramHeader h;
  h.magic = r.get_u16();
  h.framing_version = r.get_u8();
  h.message_id = r.get_u8();
  h.message_version = r.get_u8();
  h.unit_id = r.get_u8();
  h.length = r.get_u16();
  h.datagram_seq = r.get_u32();
  if (h.magic != kUdpMagic) return DecodeError::kBadMagic;
  if (header != nullptr) *header = h;  // as read: a refused version is named by it
  if (h.framing_version != kUdpFramingVersion) return DecodeError::kBadVersion;
  if (h.length != in.size() || in.size() > kMaxDatagramBytes) return DecodeError::kBadLength;
  const std::size_t covered = in.size() - kUdpCrcBytes;
  bytes::BigEndianReader crc_reader(in.subspan(covered));
  if (crc_reader.get_u32() != crc32(in.first(covered))) return DecodeError::kBadCrc;
  const auto payload = in.subspan(kUdpHeaderBytes, covered - kUdpHeaderBytes);
  DecodeError e = DecodeError::kUnknownType;
  switch (static_cast<MessageId>(h.message_id)) {
    case MessageId::kMarkObservations:
      if (h.message_version != kMarkObservationsVersion) return DecodeError::kBadVersion;
      e = decode_payload<MarkObservations>(payload, h.unit_id, out);
      break;
    case MessageId::kUnitHealth:
      if (h.message_version != kUnitHealthVersion) return DecodeError::kBadVersion;
      e = decode_payload<UnitHealth>(payload, h.unit_id, out);
      break;
    default:  // FtiSample is not sent in this framing (host output, docs/fti-output.md)
      return DecodeError::kUnknownType;
  }
  return e;
}

}  // namespace storetrack::msg
