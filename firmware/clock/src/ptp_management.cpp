#include "storetrack/clock/ptp_management.hpp"

#include <cerrno>

#include "big_endian.hpp"

namespace storetrack::clock {
namespace {

using detail::BigEndianReader;
using detail::BigEndianWriter;

void write_port_identity(BigEndianWriter& w, const PortIdentity& id) {
  for (const std::uint8_t b : id.clock_identity)
    w.u8(b);
  w.u16(id.port_number);
}

PortIdentity read_port_identity(BigEndianReader& r) {
  PortIdentity id;
  r.copy(id.clock_identity);
  id.port_number = r.u16();
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
  w.u8(static_cast<std::uint8_t>((header.transport_specific << 4) | kMessageTypeManagement));
  w.u8(kPtpVersion);
  w.u16(static_cast<std::uint16_t>(kGetRequestBytes));
  w.u8(header.domain_number);
  w.u8(0);   // reserved
  w.u16(0);  // flagField
  w.u64(0);  // correctionField
  w.u32(0);  // reserved
  write_port_identity(w, header.source);
  w.u16(header.sequence_id);
  w.u8(kControlManagement);
  w.u8(0x7F);  // logMessageInterval: 0x7F for management messages (13.3.2.14)
  // Management message fields (15.4.1): every port of the clock behind the socket, no hops.
  for (int i = 0; i < 8; ++i)
    w.u8(0xFF);
  w.u16(0xFFFF);
  w.u8(0);  // startingBoundaryHops
  w.u8(0);  // boundaryHops
  w.u8(static_cast<std::uint8_t>(ManagementAction::kGet));
  w.u8(0);  // reserved
  // Management TLV (15.5.2) with an empty dataField, as pmc sends GETs.
  w.u16(kTlvManagement);
  w.u16(2);  // lengthField: the managementId only
  w.u16(static_cast<std::uint16_t>(id));
  if (w.failed()) return -ENOBUFS;
  return static_cast<int>(w.offset());
}

ReplyStatus decode_reply(std::span<const std::uint8_t> bytes, std::uint16_t sequence_id,
                         ManagementId id, ManagementReply& out) {
  if (bytes.size() < kManagementHeaderBytes + kTlvHeaderBytes + 2) return ReplyStatus::kTooShort;
  BigEndianReader r(bytes);
  const std::uint8_t type = r.u8() & 0x0F;
  const std::uint8_t version = r.u8() & 0x0F;
  if (type != kMessageTypeManagement || version != kPtpVersion) return ReplyStatus::kNotManagement;
  const std::uint16_t message_length = r.u16();
  if (message_length > bytes.size() ||
      message_length < kManagementHeaderBytes + kTlvHeaderBytes + 2)
    return ReplyStatus::kTooShort;
  r.skip(1 + 1 + 2 + 8 + 4);  // domainNumber, reserved, flagField, correctionField, reserved
  out.source = read_port_identity(r);
  out.sequence_id = r.u16();
  if (out.sequence_id != sequence_id) return ReplyStatus::kWrongSequence;
  r.skip(2 + 10 + 2);  // controlField, logMessageInterval, targetPortIdentity, boundary hops
  if ((r.u8() & 0x0F) != static_cast<std::uint8_t>(ManagementAction::kResponse))
    return ReplyStatus::kNotResponse;
  r.skip(1);
  const std::uint16_t tlv_type = r.u16();
  const std::uint16_t tlv_length = r.u16();
  // The TLV must lie inside the message (messageLength bounds it, not the datagram size).
  if (tlv_length < 2 || kManagementHeaderBytes + kTlvHeaderBytes + tlv_length > message_length)
    return ReplyStatus::kTooShort;
  if (tlv_type == kTlvManagementErrorStatus) {
    // managementErrorId, managementId, reserved(4), displayData (15.5.4.1).
    out.error_id = r.u16();
    out.id = static_cast<ManagementId>(tlv_length >= 4 ? r.u16() : 0);
    return ReplyStatus::kErrorStatus;
  }
  if (tlv_type != kTlvManagement) return ReplyStatus::kUnexpectedTlv;
  out.id = static_cast<ManagementId>(r.u16());
  if (out.id != id) return ReplyStatus::kWrongId;
  out.data = bytes.subspan(r.offset(), tlv_length - 2u);
  out.error_id = 0;
  return r.failed() ? ReplyStatus::kTooShort : ReplyStatus::kOk;
}

bool parse_port_data_set(std::span<const std::uint8_t> data, PortDataSet& out) {
  if (data.size() < kPortDataSetBytes) return false;
  BigEndianReader r(data);
  out.port_identity = read_port_identity(r);
  out.port_state = static_cast<PortState>(r.u8());
  r.skip(1 + 8);  // logMinDelayReqInterval, peerMeanPathDelay
  out.log_announce_interval = r.i8();
  out.announce_receipt_timeout = r.u8();
  out.log_sync_interval = r.i8();
  return !r.failed();
}

bool parse_time_status_np(std::span<const std::uint8_t> data, TimeStatusNp& out) {
  if (data.size() < kTimeStatusNpBytes) return false;
  BigEndianReader r(data);
  out.master_offset_ns = r.i64();
  out.ingress_time_ns = r.i64();
  out.cumulative_scaled_rate_offset = r.i32();
  out.scaled_last_gm_phase_change = r.i32();
  out.gm_time_base_indicator = r.u16();
  r.skip(12);  // lastGmPhaseChange (ScaledNs: 96 bits)
  out.gm_present = r.i32() != 0;
  r.copy(out.gm_identity);
  return !r.failed();
}

bool parse_time_properties(std::span<const std::uint8_t> data, TimePropertiesDataSet& out) {
  if (data.size() < kTimePropertiesDataSetBytes) return false;
  BigEndianReader r(data);
  out.current_utc_offset_s = r.i16();
  out.flags = r.u8();
  out.time_source = r.u8();
  return !r.failed();
}

bool TimePropertiesDataSet::time_traceable() const {
  return (flags & time_properties_flags::kTimeTraceable) != 0;
}
bool TimePropertiesDataSet::frequency_traceable() const {
  return (flags & time_properties_flags::kFrequencyTraceable) != 0;
}

}  // namespace storetrack::clock
