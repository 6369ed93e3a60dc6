// IEEE 1588-2008 management messages (clause 15), as ptp4l (linuxptp) answers them on its UNIX
// domain socket: the GET requests `pmc` sends and the three replies the clock monitor reads.
//
// Wire layout of one management message (all multi-byte fields big-endian):
//   0  header (34 bytes): transportSpecific|messageType(0xD), versionPTP(2), messageLength,
//      domainNumber, reserved, flagField, correctionField, reserved, sourcePortIdentity(10),
//      sequenceId, controlField(0x04 = management), logMessageInterval(0x7F)
//  34  targetPortIdentity (clockIdentity 8 + portNumber 2)
//  44  startingBoundaryHops, boundaryHops, reserved|actionField, reserved
//  48  TLV: tlvType (0x0001 MANAGEMENT / 0x0002 MANAGEMENT_ERROR_STATUS), lengthField,
//      managementId, dataField (lengthField - 2 bytes)
// Encoding and decoding allocate nothing and throw nothing; a reply that does not fit this
// layout is a ReplyStatus, never a crash.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

namespace storetrack::clock {

inline constexpr std::size_t kPtpHeaderBytes = 34;
inline constexpr std::size_t kManagementHeaderBytes = 48;  ///< header + target .. reserved
inline constexpr std::size_t kTlvHeaderBytes = 4;          ///< tlvType + lengthField
/// A GET request as pmc sends it: the management TLV carries only the managementId.
inline constexpr std::size_t kGetRequestBytes = kManagementHeaderBytes + kTlvHeaderBytes + 2;
/// Largest reply this decoder accepts (ptp4l's message buffer is 1500 bytes).
inline constexpr std::size_t kMaxReplyBytes = 1500;

inline constexpr std::uint8_t kMessageTypeManagement = 0xD;
inline constexpr std::uint8_t kPtpVersion = 2;
inline constexpr std::uint8_t kControlManagement = 0x04;
inline constexpr std::uint16_t kTlvManagement = 0x0001;
inline constexpr std::uint16_t kTlvManagementErrorStatus = 0x0002;

enum class ManagementAction : std::uint8_t {
  kGet = 0,
  kSet = 1,
  kResponse = 2,
  kCommand = 3,
  kAcknowledge = 4
};

/// managementId values (IEEE 1588-2008 table 40; TIME_STATUS_NP is linuxptp's own).
enum class ManagementId : std::uint16_t {
  kTimePropertiesDataSet = 0x2003,
  kPortDataSet = 0x2004,
  kTimeStatusNp = 0xC000,
};

/// portState (IEEE 1588-2008 table 8).
enum class PortState : std::uint8_t {
  kUnknown = 0,  ///< not a standard value: no reply yet
  kInitializing = 1,
  kFaulty = 2,
  kDisabled = 3,
  kListening = 4,
  kPreMaster = 5,
  kMaster = 6,
  kPassive = 7,
  kUncalibrated = 8,
  kSlave = 9,
};
const char* to_string(PortState s);

struct PortIdentity {
  std::array<std::uint8_t, 8> clock_identity{};
  std::uint16_t port_number = 0;
};

/// What a request needs besides its managementId (pmc's -d, -t; boundary hops are 0: only the
/// ptp4l behind the socket answers, nothing is forwarded onto the network).
struct RequestHeader {
  std::uint8_t domain_number = 0;
  std::uint8_t transport_specific = 0;
  PortIdentity source{};  ///< the requester; ptp4l addresses its reply to it
  std::uint16_t sequence_id = 0;
};

/// Writes a GET for `id` into `out`; returns the message length (kGetRequestBytes) or -ENOBUFS.
int encode_get_request(const RequestHeader& header, ManagementId id, std::span<std::uint8_t> out);

enum class ReplyStatus : std::uint8_t {
  kOk = 0,
  kTooShort,         ///< fewer bytes than the headers, or than messageLength / lengthField say
  kNotManagement,    ///< messageType is not 0xD, or versionPTP is not 2
  kWrongSequence,    ///< sequenceId differs from the request's (a late reply to an old one)
  kNotResponse,      ///< actionField is not RESPONSE
  kUnexpectedTlv,    ///< neither MANAGEMENT nor MANAGEMENT_ERROR_STATUS
  kWrongId,          ///< managementId differs from the request's
  kErrorStatus,      ///< ptp4l answered with MANAGEMENT_ERROR_STATUS (error_id says which)
  kDataSetTooShort,  ///< the data field is shorter than the data set's layout
};
const char* to_string(ReplyStatus s);

/// A decoded reply: the management TLV's data field (a view into the received bytes).
struct ManagementReply {
  PortIdentity source{};
  std::uint16_t sequence_id = 0;
  ManagementId id{};
  std::uint16_t error_id = 0;  ///< managementErrorId when kErrorStatus
  std::span<const std::uint8_t> data{};
};

/// Checks the headers and the first TLV of `bytes` against the request (`sequence_id`, `id`).
ReplyStatus decode_reply(std::span<const std::uint8_t> bytes, std::uint16_t sequence_id,
                         ManagementId id, ManagementReply& out);

/// PORT_DATA_SET (IEEE 1588-2008 15.5.3.3.1; 26 bytes, newer linuxptp appends more).
struct PortDataSet {
  PortIdentity port_identity{};
  PortState port_state = PortState::kUnknown;
  std::int8_t log_announce_interval = 0;
  std::uint8_t announce_receipt_timeout = 0;
  std::int8_t log_sync_interval = 0;
};
inline constexpr std::size_t kPortDataSetBytes = 26;

/// TIME_STATUS_NP (linuxptp tlv.h struct time_status_np; 50 bytes).
struct TimeStatusNp {
  std::int64_t master_offset_ns = 0;  ///< slave - master, ns (ptp4l's last measurement)
  std::int64_t ingress_time_ns = 0;   ///< local time of that measurement's Sync, ns
  std::int32_t cumulative_scaled_rate_offset = 0;
  std::int32_t scaled_last_gm_phase_change = 0;
  std::uint16_t gm_time_base_indicator = 0;
  bool gm_present = false;  ///< ptp4l: the grandmaster is another clock than this one
  std::array<std::uint8_t, 8> gm_identity{};
};
inline constexpr std::size_t kTimeStatusNpBytes = 50;

/// TIME_PROPERTIES_DATA_SET (IEEE 1588-2008 15.5.3.6.1; 4 bytes).
struct TimePropertiesDataSet {
  std::int16_t current_utc_offset_s = 0;
  std::uint8_t flags = 0;  ///< time_properties_flags
  std::uint8_t time_source = 0;
  bool time_traceable() const;
  bool frequency_traceable() const;
};
inline constexpr std::size_t kTimePropertiesDataSetBytes = 4;

namespace time_properties_flags {
inline constexpr std::uint8_t kLeap61 = 0x01;
inline constexpr std::uint8_t kLeap59 = 0x02;
inline constexpr std::uint8_t kUtcOffsetValid = 0x04;
inline constexpr std::uint8_t kPtpTimescale = 0x08;
inline constexpr std::uint8_t kTimeTraceable = 0x10;
inline constexpr std::uint8_t kFrequencyTraceable = 0x20;
}  // namespace time_properties_flags

/// Data-field parsers: false when `data` is shorter than the layout.
bool parse_port_data_set(std::span<const std::uint8_t> data, PortDataSet& out);
bool parse_time_status_np(std::span<const std::uint8_t> data, TimeStatusNp& out);
bool parse_time_properties(std::span<const std::uint8_t> data, TimePropertiesDataSet& out);

}  // namespace storetrack::clock
