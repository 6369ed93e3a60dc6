// UDP framing: round trips, every corruption detected, every malformed input a typed error.
#include <gtest/gtest.h>

#include <array>
#include <cerrno>
#include <random>
#include <vector>

#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/msg/crc.hpp"
#include "storetrack/msg/udp_codec.hpp"
#include "test_helpers.hpp"

namespace storetrack::msg {
namespace {

using Buffer = std::array<std::uint8_t, kMaxDatagramBytes>;

void expect_same_header_fields(const MarkObservations& in, const MarkObservations& out) {
  EXPECT_EQ(out.unit_id, in.unit_id);
  EXPECT_EQ(out.camera_id, in.camera_id);
  EXPECT_EQ(out.trigger_seq, in.trigger_seq);
  EXPECT_EQ(out.exposure_start_tai_ns, in.exposure_start_tai_ns);
  EXPECT_EQ(out.exposure_start_mono_ns, in.exposure_start_mono_ns);
  EXPECT_EQ(out.exposure_duration_ns, in.exposure_duration_ns);
  EXPECT_EQ(out.clock_state, in.clock_state);
  EXPECT_EQ(out.flags, in.flags);
  ASSERT_EQ(out.mark_count, in.mark_count);
}

void expect_marks_quantised(const MarkObservations& in, const MarkObservations& out) {
  for (std::size_t i = 0; i < in.mark_count; ++i) {
    const MarkObservation& a = in.marks[i];
    const MarkObservation& b = out.marks[i];
    EXPECT_LE(std::abs(b.x_px - a.x_px), 1.0 / 512.0 + 1e-6);
    EXPECT_LE(std::abs(b.y_px - a.y_px), 1.0 / 512.0 + 1e-6);
    EXPECT_LE(std::abs(std::log2(b.sigma_px / a.sigma_px)), 1.0 / 32.0 + 1e-6);
    EXPECT_EQ(b.peak, a.peak);
    EXPECT_LE(std::abs(b.diameter_px - a.diameter_px), 0.25 + 1e-6);
    EXPECT_EQ(b.flags, a.flags);
  }
}

void expect_same(const UnitHealth& a, const UnitHealth& b) {
  EXPECT_EQ(a.unit_id, b.unit_id);
  EXPECT_EQ(a.clock_state, b.clock_state);
  EXPECT_EQ(a.uptime_s, b.uptime_s);
  EXPECT_EQ(a.report_tai_ns, b.report_tai_ns);
  EXPECT_EQ(a.ptp_offset_ns, b.ptp_offset_ns);
  EXPECT_EQ(a.sensor_temp_cdeg, b.sensor_temp_cdeg);
  EXPECT_EQ(a.board_temp_cdeg, b.board_temp_cdeg);
  EXPECT_EQ(a.frames_captured, b.frames_captured);
  EXPECT_EQ(a.frames_dropped, b.frames_dropped);
  EXPECT_EQ(a.triggers_seen, b.triggers_seen);
  EXPECT_EQ(a.triggers_missing, b.triggers_missing);
  EXPECT_EQ(a.triggers_extra, b.triggers_extra);
  EXPECT_EQ(a.observations_sent, b.observations_sent);
  EXPECT_EQ(a.link_tx_errors, b.link_tx_errors);
  EXPECT_EQ(a.link_tx_dropped, b.link_tx_dropped);
  EXPECT_EQ(a.can_bus_off_count, b.can_bus_off_count);
  EXPECT_EQ(a.can_error_frames, b.can_error_frames);
  EXPECT_EQ(a.centroid_time_us_max, b.centroid_time_us_max);
  EXPECT_EQ(a.status, b.status);
}

// Rewrites the CRC trailer so that a deliberately malformed datagram reaches the later checks.
void reseal(std::span<std::uint8_t> datagram) {
  const std::size_t covered = datagram.size() - kUdpCrcBytes;
  bytes::BigEndianWriter w(datagram.subspan(covered));
  w.put_u32(crc32(datagram.first(covered)));
}

TEST(MsgUdp, MarkObservationsRoundTrip) {
  std::mt19937_64 rng(2);
  Buffer buf;
  for (int i = 0; i < 3000; ++i) {
    const MarkObservations in = test::random_observations(rng);
    const std::uint32_t seq = static_cast<std::uint32_t>(rng());
    const int n = encode_datagram(in, buf, seq);
    ASSERT_EQ(n, static_cast<int>(kUdpHeaderBytes + kUdpCrcBytes + kMarkObservationsFixedBytes +
                                  8 * in.mark_count));
    AnyMessage any;
    DatagramHeader header;
    ASSERT_EQ(decode_datagram(std::span(buf).first(static_cast<std::size_t>(n)), any, &header),
              DecodeError::kNone);
    ASSERT_TRUE(std::holds_alternative<MarkObservations>(any));
    const auto& out = std::get<MarkObservations>(any);
    expect_same_header_fields(in, out);
    expect_marks_quantised(in, out);
    EXPECT_EQ(header.datagram_seq, seq);
    EXPECT_EQ(header.unit_id, in.unit_id);
    EXPECT_EQ(header.length, n);
    EXPECT_EQ(header.message_id, static_cast<std::uint8_t>(MessageId::kMarkObservations));
  }
}

TEST(MsgUdp, UnitHealthRoundTrip) {
  std::mt19937_64 rng(3);
  Buffer buf;
  for (int i = 0; i < 1000; ++i) {
    const UnitHealth in = test::random_health(rng);
    const int n = encode_datagram(in, buf, 7);
    ASSERT_EQ(n, static_cast<int>(kUdpHeaderBytes + kUnitHealthFixedBytes + kUdpCrcBytes));
    AnyMessage any;
    ASSERT_EQ(decode_datagram(std::span(buf).first(static_cast<std::size_t>(n)), any),
              DecodeError::kNone);
    ASSERT_TRUE(std::holds_alternative<UnitHealth>(any));
    expect_same(in, std::get<UnitHealth>(any));
  }
}

TEST(MsgUdp, MaximumMarksFillTheLargestDatagram) {
  std::mt19937_64 rng(4);
  MarkObservations in = test::random_observations(rng, static_cast<int>(kMaxMarks));
  Buffer buf;
  ASSERT_EQ(encode_datagram(in, buf), static_cast<int>(kMaxDatagramBytes));
  AnyMessage any;
  ASSERT_EQ(decode_datagram(buf, any), DecodeError::kNone);
  expect_marks_quantised(in, std::get<MarkObservations>(any));
  // Every smaller buffer is refused without writing past it.
  for (std::size_t size = 0; size < kMaxDatagramBytes; ++size) {
    std::vector<std::uint8_t> small(size + 1, 0xA5);
    EXPECT_EQ(encode_datagram(in, std::span(small).first(size)), -ENOSPC) << size;
    EXPECT_EQ(small[size], 0xA5);
  }
  in.mark_count = kMaxMarks + 1;
  EXPECT_EQ(encode_datagram(in, buf), -ERANGE);
  in.mark_count = 3;
  in.marks[1].x_px = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(encode_datagram(in, buf), -ERANGE);
}

TEST(MsgUdp, EverySingleBitFlipIsDetected) {
  std::mt19937_64 rng(5);
  Buffer buf;
  const MarkObservations in = test::random_observations(rng, 23);
  const int n = encode_datagram(in, buf, 99);
  ASSERT_GT(n, 0);
  const auto datagram = std::span(buf).first(static_cast<std::size_t>(n));
  DecodeCounters counters;
  for (std::size_t bit = 0; bit < datagram.size() * 8; ++bit) {
    datagram[bit / 8] ^= static_cast<std::uint8_t>(1u << (bit % 8));
    AnyMessage any;
    const DecodeError e = decode_datagram(datagram, any);
    EXPECT_NE(e, DecodeError::kNone) << "bit " << bit;
    counters.record(e);
    datagram[bit / 8] ^= static_cast<std::uint8_t>(1u << (bit % 8));
  }
  EXPECT_EQ(counters.errors(), datagram.size() * 8);
  EXPECT_GT(counters.count(DecodeError::kBadCrc), datagram.size() * 8 / 2);  // payload flips
  EXPECT_GT(counters.count(DecodeError::kBadMagic), 0u);
  AnyMessage any;
  EXPECT_EQ(decode_datagram(datagram, any), DecodeError::kNone);  // restored
}

TEST(MsgUdp, TruncationAtEveryLengthAndExtensionAreErrors) {
  std::mt19937_64 rng(6);
  Buffer buf;
  for (int mark_count : {0, 1, 23, 64}) {
    const MarkObservations in = test::random_observations(rng, mark_count);
    const int n = encode_datagram(in, buf);
    ASSERT_GT(n, 0);
    for (int len = 0; len < n; ++len) {
      AnyMessage any;
      const DecodeError e =
          decode_datagram(std::span(buf).first(static_cast<std::size_t>(len)), any);
      EXPECT_TRUE(e == DecodeError::kTooShort || e == DecodeError::kBadLength) << len;
    }
    std::vector<std::uint8_t> longer(buf.begin(), buf.begin() + n);
    longer.push_back(0);
    AnyMessage any;
    EXPECT_EQ(decode_datagram(longer, any), DecodeError::kBadLength);
  }
}

TEST(MsgUdp, EachMalformationHasItsTypedError) {
  std::mt19937_64 rng(7);
  Buffer buf;
  const MarkObservations in = test::random_observations(rng, 5);
  const int n = encode_datagram(in, buf);
  ASSERT_GT(n, 0);
  const std::size_t size = static_cast<std::size_t>(n);
  const std::size_t mark_count_offset = kUdpHeaderBytes + kMarkObservationsFixedBytes - 1;
  const std::size_t clock_state_offset = kUdpHeaderBytes + 26;
  ASSERT_EQ(kMarkObservationsFields[6].name, "clock_state");
  ASSERT_EQ(kMarkObservationsFields[6].offset, 26);
  struct Case {
    const char* what;
    std::size_t offset;
    std::uint8_t value;
    bool reseal;
    DecodeError expected;
  };
  const Case cases[] = {
      {"magic", 0, 0x00, true, DecodeError::kBadMagic},
      {"framing version", 2, 2, true, DecodeError::kBadVersion},
      {"message version", 4, 9, true, DecodeError::kBadVersion},
      {"message id", 3, 0x7E, true, DecodeError::kUnknownType},
      {"FtiSample is not a UDP message", 3, 0x10, true, DecodeError::kUnknownType},
      {"length field", 7, static_cast<std::uint8_t>(size + 1), true, DecodeError::kBadLength},
      {"payload bit without reseal", 20, 0x55, false, DecodeError::kBadCrc},
      {"header unit differs from payload unit", 5, static_cast<std::uint8_t>(in.unit_id + 1), true,
       DecodeError::kOutOfRange},
      {"mark_count 65", mark_count_offset, 65, true, DecodeError::kOutOfRange},
      {"mark_count 200", mark_count_offset, 200, true, DecodeError::kOutOfRange},
      {"mark_count disagrees with the length", mark_count_offset, 6, true, DecodeError::kBadLength},
      {"clock_state 4", clock_state_offset, 4, true, DecodeError::kOutOfRange},
  };
  for (const Case& c : cases) {
    std::vector<std::uint8_t> d(buf.begin(), buf.begin() + n);
    d[c.offset] = c.value;
    if (c.reseal) reseal(d);
    AnyMessage any;
    EXPECT_EQ(decode_datagram(d, any), c.expected) << c.what;
  }
  // clock_state "invalid" (0xFF) is a legal value: not available.
  {
    std::vector<std::uint8_t> d(buf.begin(), buf.begin() + n);
    d[clock_state_offset] = 0xFF;
    reseal(d);
    AnyMessage any;
    EXPECT_EQ(decode_datagram(d, any), DecodeError::kNone);
  }
  // A mark whose x carries the reserved all-ones code.
  {
    std::vector<std::uint8_t> d(buf.begin(), buf.begin() + n);
    const std::size_t mark0 = kUdpHeaderBytes + kMarkObservationsFixedBytes;
    d[mark0] = 0xFF;
    d[mark0 + 1] = 0xFF;
    d[mark0 + 2] |= 0xE0;  // 19 bits of x: 8 + 8 + 3
    reseal(d);
    AnyMessage any;
    EXPECT_EQ(decode_datagram(d, any), DecodeError::kOutOfRange);
  }
  EXPECT_STREQ(to_string(DecodeError::kBadCrc), "CRC mismatch");
}

TEST(MsgUdp, RandomGarbageNeverCrashesAndIsCounted) {
  std::mt19937_64 rng(8);
  DecodeCounters counters;
  std::vector<std::uint8_t> d;
  constexpr int kTrials = 200000;
  for (int i = 0; i < kTrials; ++i) {
    const bool structured = i % 2 == 0;
    const std::uint8_t id = static_cast<std::uint8_t>(rng() % 3);  // 0 is unknown
    const std::size_t marks = rng() % (kMaxMarks + 2);
    if (structured && id != 0) {
      // A plausible header, the right size and a valid CRC, so that the payload checks run.
      d.resize(kUdpHeaderBytes + kUdpCrcBytes +
               (id == 1 ? kMarkObservationsFixedBytes + 8 * marks : kUnitHealthFixedBytes));
    } else {
      d.resize(rng() % (kMaxDatagramBytes + 64));
    }
    for (auto& b : d)
      b = static_cast<std::uint8_t>(rng());
    if (structured && d.size() >= kUdpHeaderBytes + kUdpCrcBytes) {
      bytes::BigEndianWriter w(d);
      w.put_u16(kUdpMagic);
      w.put_u8(kUdpFramingVersion);
      w.put_u8(id);
      w.put_u8(1);
      w.put_u8(d[kUdpHeaderBytes]);  // unit id as in the payload
      w.put_u16(static_cast<std::uint16_t>(d.size()));
      if (id == 1) {
        d[kUdpHeaderBytes + 26] = static_cast<std::uint8_t>(rng() % 5);  // clock_state
        d[kUdpHeaderBytes + kMarkObservationsFixedBytes - 1] = static_cast<std::uint8_t>(marks);
      } else if (id == 2) {
        d[kUdpHeaderBytes + 1] = static_cast<std::uint8_t>(rng() % 5);
      }
      reseal(d);
    }
    AnyMessage any;
    const DecodeError e = decode_datagram(d, any);
    counters.record(e);
    if (e == DecodeError::kNone) {
      // Whatever is accepted is canonical: encoding it again reproduces the datagram.
      Buffer again;
      const std::uint32_t seq = bytes::BigEndianReader(std::span(d).subspan(8)).get_u32();
      const int n = std::visit([&](const auto& m) { return encode_datagram(m, again, seq); }, any);
      ASSERT_EQ(n, static_cast<int>(d.size()));
      EXPECT_TRUE(std::equal(d.begin(), d.end(), again.begin()));
    }
  }
  std::uint64_t total = 0;
  for (auto c : counters.by_error)
    total += c;
  EXPECT_EQ(total, static_cast<std::uint64_t>(kTrials));
  EXPECT_GT(counters.count(DecodeError::kBadMagic), 0u);
  EXPECT_GT(counters.count(DecodeError::kBadLength), 0u);
  EXPECT_GT(counters.count(DecodeError::kOutOfRange), 0u);
  EXPECT_GT(counters.ok(), static_cast<std::uint64_t>(kTrials / 20));
}

}  // namespace
}  // namespace storetrack::msg
