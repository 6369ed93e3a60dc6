#include "storetrack/clock/ptp_management.hpp"

#include <cerrno>

#include "storetrack/bytes/byte_cursor.hpp"

// PTP's network byte order is big-endian (IEEE 1588-2008 5.3): every field of a management
// message goes through the common byte cursor, so a short reply is a checked condition.
namespace storetrack::clock {
namespace {

using bytes::BigEndianReader;
using bytes::BigEndianWriter;

void write_port_identity(BigEndianWriter& w, const PortIdentity& id) {
  w.put_bytes(id.clock_identity);
  w.put_u16(id.port_number);
}

PortIdentity read_port_identity(BigEndianReader& r) {
  PortIdentity id;
  r.get_bytes(id.clock_identity);
  id.port_number = r.get_u16();
  return id;
}

}  // namespace

const char* to_string(PortState s) {
  switch (s) {
    case PortState::kUnknown:
      return "unknown";
    case PortState::kInitializing:
      return "INITIALIZING";
    case PortState::kFaulty:
      return "FAULTY";
    case PortState::kDisabled:
      return "DISABLED";
    case PortState::kListening:
      return "LISTENING";
    case PortState::kPreMaster:
      return "PRE_MASTER";
    case PortState::kMaster:
      return "MASTER";
    case PortState::kPassive:
      return "PASSIVE";
    case PortState::kUncalibrated:
      return "UNCALIBRATED";
    case PortState::kSlave:
      return "SLAVE";
  }
  return "invalid";
}

const char* to_string(ReplyStatus s) {
  switch (s) {
    case ReplyStatus::kOk:
      return "ok";
    case ReplyStatus::kTooShort:
      return "too short";
    case ReplyStatus::kNotManagement:
      return "not a PTP v2 management message";
    case ReplyStatus::kWrongSequence:
      return "wrong sequenceId";
    case ReplyStatus::kNotResponse:
      return "actionField not RESPONSE";
    case ReplyStatus::kUnexpectedTlv:
      return "unexpected TLV type";
    case ReplyStatus::kWrongId:
      return "wrong managementId";
    case ReplyStatus::kErrorStatus:
      return "MANAGEMENT_ERROR_STATUS";
    case ReplyStatus::kDataSetTooShort:
      return "data set too short";
  }
  return "invalid";
}

int encode_get_request(const RequestHeader& header, ManagementId id, std::span<std::uint8_t> out) {
  BigEndianWriter w(out);
  // Header (IEEE 1588-2008 13.3).
  w.put_u8(static_cast<std::uint8_t>((header.transport_specific << 4) | kMessageTypeManagement));
  w.put_u8(kPtpVersion);
  w.put_u16(static_cast<std::uint16_t>(kGetRequestBytes));
  w.put_u8(header.domain_number);
  w.put_u8(0);   // reserved
  w.put_u16(0);  // flagField
  w.put_u64(0);  // correctionField
  w.put_u32(0);  // reserved
  write_port_identity(w, header.source);
  w.put_u16(header.sequence_id);
  w.put_u8(kControlManagement);
  w.put_u8(0x7F);  // logMessageInterval: 0x7F for management messages (13.3.2.14)
  // Management message fields (15.4.1): every port of the clock behind the socket, no hops.
  for (int i = 0; i < 8; ++i)
    w.put_u8(0xFF);
  w.put_u16(0xFFFF);
  w.put_u8(0);  // startingBoundaryHops
  w.put_u8(0);  // boundaryHops
  w.put_u8(static_cast<std::uint8_t>(ManagementAction::kGet));
  w.put_u8(0);  // reserved
  // Management TLV (15.5.2) with an empty dataField, as pmc sends GETs.
  w.put_u16(kTlvManagement);
  w.put_u16(2);  // lengthField: the managementId only
  w.put_u16(static_cast<std::uint16_t>(id));
  if (!w.ok()) return -ENOBUFS;
  return static_cast<int>(w.size());
}

ReplyStatus decode_reply(std::span<const std::uint8_t> bytes, std::uint16_t sequence_id,
                         ManagementId id, ManagementReply& out) {
  if (bytes.size() < kManagementHeaderBytes + kTlvHeaderBytes + 2) return ReplyStatus::kTooShort;
  BigEndianReader r(bytes);
  const std::uint8_t type = r.get_u8() & 0x0F;
  const std::uint8_t version = r.get_u8() & 0x0F;
  if (type != kMessageTypeManagement || version != kPtpVersion) return ReplyStatus::kNotManagement;
  const std::uint16_t message_length = r.get_u16();
  if (message_length > bytes.size() ||
      message_length < kManagementHeaderBytes + kTlvHeaderBytes + 2)
    return ReplyStatus::kTooShort;
  r.skip(1 + 1 + 2 + 8 + 4);  // domainNumber, reserved, flagField, correctionField, reserved
  out.source = read_port_identity(r);
  out.sequence_id = r.get_u16();
  if (out.sequence_id != sequence_id) return ReplyStatus::kWrongSequence;
  r.skip(2 + 10 + 2);  // controlField, logMessageInterval, targetPortIdentity, boundary hops
  if ((r.get_u8() & 0x0F) != static_cast<std::uint8_t>(ManagementAction::kResponse))
    return ReplyStatus::kNotResponse;
  r.skip(1);
  const std::uint16_t tlv_type = r.get_u16();
  const std::uint16_t tlv_length = r.get_u16();
  // The TLV must lie inside the message (messageLength bounds it, not the datagram size).
  if (tlv_length < 2 || kManagementHeaderBytes + kTlvHeaderBytes + tlv_length > message_length)
    return ReplyStatus::kTooShort;
  if (tlv_type == kTlvManagementErrorStatus) {
    // managementErrorId, managementId, reserved(4), displayData (15.5.4.1).
    out.error_id = r.get_u16();
    out.id = static_cast<ManagementId>(tlv_length >= 4 ? r.get_u16() : 0);
    return ReplyStatus::kErrorStatus;
  }
  if (tlv_type != kTlvManagement) return ReplyStatus::kUnexpectedTlv;
  out.id = static_cast<ManagementId>(r.get_u16());
  if (out.id != id) return ReplyStatus::kWrongId;
  if (!r.ok()) return ReplyStatus::kTooShort;
  out.data = bytes.subspan(r.position(), tlv_length - 2u);
  out.error_id = 0;
  return ReplyStatus::kOk;
}

bool parse_port_data_set(std::span<const std::uint8_t> data, PortDataSet& out) {
  if (data.size() < kPortDataSetBytes) return false;
  BigEndianReader r(data);
  out.port_identity = read_port_identity(r);
  out.port_state = static_cast<PortState>(r.get_u8());
  r.skip(1 + 8);  // logMinDelayReqInterval, peerMeanPathDelay
  out.log_announce_interval = r.get_i8();
  out.announce_receipt_timeout = r.get_u8();
  out.log_sync_interval = r.get_i8();
  return !!r.ok();
}

bool parse_time_status_np(std::span<const std::uint8_t> data, TimeStatusNp& out) {
  if (data.size() < kTimeStatusNpBytes) return false;
  BigEndianReader r(data);
  out.master_offset_ns = r.get_i64();
  out.ingress_time_ns = r.get_i64();
  out.cumulative_scaled_rate_offset = r.get_i32();
  out.scaled_last_gm_phase_change = r.get_i32();
  out.gm_time_base_indicator = r.get_u16();
  r.skip(12);  // lastGmPhaseChange (ScaledNs: 96 bits)
  out.gm_present = r.get_i32() != 0;
  r.get_bytes(out.gm_identity);
  return !!r.ok();
}

bool parse_time_properties(std::span<const std::uint8_t> data, TimePropertiesDataSet& out) {
  if (data.size() < kTimePropertiesDataSetBytes) return false;
  BigEndianReader r(data);
  out.current_utc_offset_s = r.get_i16();
  out.flags = r.get_u8();
  out.time_source = r.get_u8();
  return !!r.ok();
}

bool TimePropertiesDataSet::time_traceable() const {
  return (flags & time_properties_flags::kTimeTraceable) != 0;
}
bool TimePropertiesDataSet::frequency_traceable() const {
  return (flags & time_properties_flags::kFrequencyTraceable) != 0;
}

}  // namespace storetrack::clock
