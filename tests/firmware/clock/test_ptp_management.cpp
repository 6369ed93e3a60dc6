// The management codec against ptp4l's and pmc's own bytes (ptp4l_captures.hpp), and against
// replies broken on purpose: every malformed reply is a status, never a crash or a read past
// the datagram.
#include <gtest/gtest.h>

#include <array>
#include <vector>

#include "ptp4l_captures.hpp"
#include "storetrack/clock/ptp_management.hpp"

namespace storetrack::clock {
namespace {

using test::from_hex;

TEST(PtpManagementEncode, GetRequestsAreWhatPmcSends) {
  struct Case {
    ManagementId id;
    std::string_view pmc_bytes;
    std::uint16_t sequence_id;
  };
  const Case cases[] = {
      {ManagementId::kPortDataSet, test::kPmcGetPortDataSet, 0},
      {ManagementId::kTimeStatusNp, test::kPmcGetTimeStatusNp, 1},
      {ManagementId::kTimePropertiesDataSet, test::kPmcGetTimePropertiesDataSet, 2}};
  for (const Case& c : cases) {
    RequestHeader h;
    h.source.port_number = 0x334b;  // pmc's pid in the capture
    h.sequence_id = c.sequence_id;
    std::array<std::uint8_t, kGetRequestBytes> out{};
    ASSERT_EQ(encode_get_request(h, c.id, out), static_cast<int>(kGetRequestBytes));
    const std::vector<std::uint8_t> expected = from_hex(c.pmc_bytes);
    EXPECT_EQ(std::vector<std::uint8_t>(out.begin(), out.end()), expected)
        << "managementId 0x" << std::hex << static_cast<int>(c.id);
  }
}

TEST(PtpManagementEncode, DomainAndTransportSpecificGoWhereTheStandardSays) {
  RequestHeader h;
  h.domain_number = 24;
  h.transport_specific = 1;
  std::array<std::uint8_t, kGetRequestBytes> out{};
  ASSERT_GT(encode_get_request(h, ManagementId::kPortDataSet, out), 0);
  EXPECT_EQ(out[0], 0x1D);  // transportSpecific in the high nibble, messageType 0xD
  EXPECT_EQ(out[4], 24);    // domainNumber
}

TEST(PtpManagementEncode, ShortBufferIsRefused) {
  std::array<std::uint8_t, kGetRequestBytes - 1> out{};
  EXPECT_EQ(encode_get_request({}, ManagementId::kPortDataSet, out), -ENOBUFS);
}

TEST(PtpManagementDecode, PortDataSetOfAnUncalibratedSlave) {
  const auto bytes = from_hex(test::kSlavePortDataSetUncalibrated);
  ManagementReply reply;
  ASSERT_EQ(decode_reply(bytes, 100, ManagementId::kPortDataSet, reply), ReplyStatus::kOk);
  EXPECT_EQ(reply.sequence_id, 100);
  EXPECT_EQ(reply.source.port_number, 1);
  const std::array<std::uint8_t, 8> slave{0x5a, 0xf0, 0x04, 0xff, 0xfe, 0x47, 0xb4, 0x9f};
  EXPECT_EQ(reply.source.clock_identity, slave);
  PortDataSet ds;
  ASSERT_TRUE(parse_port_data_set(reply.data, ds));
  EXPECT_EQ(ds.port_identity.clock_identity, slave);
  EXPECT_EQ(ds.port_identity.port_number, 1);
  EXPECT_EQ(ds.port_state, PortState::kUncalibrated);
  EXPECT_EQ(ds.log_announce_interval, -2);
  EXPECT_EQ(ds.announce_receipt_timeout, 2);
  EXPECT_EQ(ds.log_sync_interval, -3);
}

TEST(PtpManagementDecode, TimeStatusNpOffsetsBothSigns) {
  const std::array<std::uint8_t, 8> master{0x86, 0x23, 0xd8, 0xff, 0xfe, 0xf0, 0x0d, 0x3a};
  ManagementReply reply;
  TimeStatusNp ts;
  auto bytes = from_hex(test::kSlaveTimeStatusNp);
  ASSERT_EQ(decode_reply(bytes, 101, ManagementId::kTimeStatusNp, reply), ReplyStatus::kOk);
  ASSERT_TRUE(parse_time_status_np(reply.data, ts));
  EXPECT_EQ(ts.master_offset_ns, 616);
  EXPECT_EQ(ts.ingress_time_ns, 1796236652230701337);
  EXPECT_TRUE(ts.gm_present);
  EXPECT_EQ(ts.gm_identity, master);
  bytes = from_hex(test::kSlaveTimeStatusNpNegative);
  ASSERT_EQ(decode_reply(bytes, 101, ManagementId::kTimeStatusNp, reply), ReplyStatus::kOk);
  ASSERT_TRUE(parse_time_status_np(reply.data, ts));
  EXPECT_EQ(ts.master_offset_ns, -316);
  EXPECT_EQ(ts.ingress_time_ns, 0x18ed83ba74e6db83);
}

TEST(PtpManagementDecode, TimePropertiesDataSet) {
  const auto bytes = from_hex(test::kSlaveTimePropertiesDataSet);
  ManagementReply reply;
  ASSERT_EQ(decode_reply(bytes, 102, ManagementId::kTimePropertiesDataSet, reply),
            ReplyStatus::kOk);
  TimePropertiesDataSet tp;
  ASSERT_TRUE(parse_time_properties(reply.data, tp));
  EXPECT_EQ(tp.current_utc_offset_s, 37);
  EXPECT_EQ(tp.time_source, 0xA0);
  EXPECT_FALSE(tp.time_traceable());
  EXPECT_FALSE(tp.frequency_traceable());
  tp.flags = time_properties_flags::kTimeTraceable | time_properties_flags::kFrequencyTraceable;
  EXPECT_TRUE(tp.time_traceable());
  EXPECT_TRUE(tp.frequency_traceable());
}

TEST(PtpManagementDecode, ErrorStatusNamesTheErrorAndTheId) {
  const auto bytes = from_hex(test::kSlaveErrorNoSuchId);
  ManagementReply reply;
  EXPECT_EQ(decode_reply(bytes, 103, ManagementId::kPortDataSet, reply), ReplyStatus::kErrorStatus);
  EXPECT_EQ(reply.error_id, 0x0002);  // NO_SUCH_ID
  EXPECT_EQ(static_cast<std::uint16_t>(reply.id), 0x1234);
}

TEST(PtpManagementDecode, LostMasterShowsInThePortStateNotInGmPresent) {
  ManagementReply reply;
  auto bytes = from_hex(test::kSlavePortDataSetListening);
  ASSERT_EQ(decode_reply(bytes, 100, ManagementId::kPortDataSet, reply), ReplyStatus::kOk);
  PortDataSet ds;
  ASSERT_TRUE(parse_port_data_set(reply.data, ds));
  EXPECT_EQ(ds.port_state, PortState::kListening);
  bytes = from_hex(test::kSlaveTimeStatusNpMasterGone);
  ASSERT_EQ(decode_reply(bytes, 101, ManagementId::kTimeStatusNp, reply), ReplyStatus::kOk);
  TimeStatusNp ts;
  ASSERT_TRUE(parse_time_status_np(reply.data, ts));
  EXPECT_TRUE(ts.gm_present);
  EXPECT_EQ(ts.ingress_time_ns, 0);
  EXPECT_EQ(ts.master_offset_ns, 720);
}

TEST(PtpManagementDecode, WrongSequenceWrongIdWrongAction) {
  const auto bytes = from_hex(test::kSlavePortDataSetUncalibrated);
  ManagementReply reply;
  EXPECT_EQ(decode_reply(bytes, 99, ManagementId::kPortDataSet, reply),
            ReplyStatus::kWrongSequence);
  EXPECT_EQ(decode_reply(bytes, 100, ManagementId::kTimeStatusNp, reply), ReplyStatus::kWrongId);
  auto get = bytes;
  get[46] = static_cast<std::uint8_t>(ManagementAction::kGet);  // actionField
  EXPECT_EQ(decode_reply(get, 100, ManagementId::kPortDataSet, reply), ReplyStatus::kNotResponse);
  auto sync = bytes;
  sync[0] = 0x00;  // messageType Sync
  EXPECT_EQ(decode_reply(sync, 100, ManagementId::kPortDataSet, reply),
            ReplyStatus::kNotManagement);
  auto v1 = bytes;
  v1[1] = 0x01;
  EXPECT_EQ(decode_reply(v1, 100, ManagementId::kPortDataSet, reply), ReplyStatus::kNotManagement);
  auto other_tlv = bytes;
  other_tlv[49] = 0x08;  // tlvType 0x0008 PATH_TRACE
  EXPECT_EQ(decode_reply(other_tlv, 100, ManagementId::kPortDataSet, reply),
            ReplyStatus::kUnexpectedTlv);
}

TEST(PtpManagementDecode, EveryTruncationIsRefused) {
  const auto bytes = from_hex(test::kSlaveTimeStatusNp);
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    const std::span<const std::uint8_t> cut(bytes.data(), n);
    ManagementReply reply;
    const ReplyStatus s = decode_reply(cut, 101, ManagementId::kTimeStatusNp, reply);
    EXPECT_EQ(s, ReplyStatus::kTooShort) << n << " bytes";
  }
}

TEST(PtpManagementDecode, LengthsThatLieAreBounded) {
  ManagementReply reply;
  auto long_message = from_hex(test::kSlaveTimeStatusNp);
  long_message[2] = 0x05;  // messageLength 0x0568 > the datagram
  EXPECT_EQ(decode_reply(long_message, 101, ManagementId::kTimeStatusNp, reply),
            ReplyStatus::kTooShort);
  auto long_tlv = from_hex(test::kSlaveTimeStatusNp);
  long_tlv[50] = 0x01;  // lengthField 0x0134 past messageLength
  EXPECT_EQ(decode_reply(long_tlv, 101, ManagementId::kTimeStatusNp, reply),
            ReplyStatus::kTooShort);
  auto zero_tlv = from_hex(test::kSlaveTimeStatusNp);
  zero_tlv[50] = 0;
  zero_tlv[51] = 0;  // lengthField 0: not even a managementId
  EXPECT_EQ(decode_reply(zero_tlv, 101, ManagementId::kTimeStatusNp, reply),
            ReplyStatus::kTooShort);
  // A shorter TLV is a valid message, but its data set is too short to parse.
  auto short_tlv = from_hex(test::kSlaveTimeStatusNp);
  short_tlv[51] = 0x10;  // lengthField 16: 14 bytes of data
  ASSERT_EQ(decode_reply(short_tlv, 101, ManagementId::kTimeStatusNp, reply), ReplyStatus::kOk);
  EXPECT_EQ(reply.data.size(), 14u);
  TimeStatusNp ts;
  EXPECT_FALSE(parse_time_status_np(reply.data, ts));
  PortDataSet ds;
  EXPECT_FALSE(parse_port_data_set(reply.data, ds));
  TimePropertiesDataSet tp;
  EXPECT_FALSE(parse_time_properties(reply.data.first(3), tp));
}

TEST(PtpManagementDecode, NewerLinuxptpLongerPortDataSetStillParses) {
  // linuxptp 4 appends iec62439 fields to PORT_DATA_SET: the standard's 26 bytes come first.
  auto bytes = from_hex(test::kSlavePortDataSetUncalibrated);
  bytes.insert(bytes.end(), {0, 0, 0, 0});
  bytes[3] = static_cast<std::uint8_t>(bytes[3] + 4);    // messageLength
  bytes[51] = static_cast<std::uint8_t>(bytes[51] + 4);  // lengthField
  ManagementReply reply;
  ASSERT_EQ(decode_reply(bytes, 100, ManagementId::kPortDataSet, reply), ReplyStatus::kOk);
  PortDataSet ds;
  ASSERT_TRUE(parse_port_data_set(reply.data, ds));
  EXPECT_EQ(ds.port_state, PortState::kUncalibrated);
}

}  // namespace
}  // namespace storetrack::clock
