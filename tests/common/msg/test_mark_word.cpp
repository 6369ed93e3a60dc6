// The 64-bit mark word, the byte-order choke point and the CRC against their specifications.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <limits>
#include <random>

#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/msg/crc.hpp"
#include "storetrack/msg/messages.hpp"
#include "test_helpers.hpp"

namespace storetrack::msg {
namespace {

void expect_mark_quantised(const MarkObservation& in, const MarkObservation& out) {
  // Rounding to the 1/256 px grid moves a coordinate by at most half a step.
  EXPECT_LE(std::abs(out.x_px - in.x_px), 1.0 / 512.0 + 1e-6) << in.x_px;
  EXPECT_LE(std::abs(out.y_px - in.y_px), 1.0 / 512.0 + 1e-6) << in.y_px;
  // sigma on a log2 grid of 1/16: within half a step in log2.
  EXPECT_LE(std::abs(std::log2(out.sigma_px / in.sigma_px)), 1.0 / 32.0 + 1e-6) << in.sigma_px;
  EXPECT_EQ(out.peak, in.peak);
  EXPECT_LE(std::abs(out.diameter_px - in.diameter_px), 0.25 + 1e-6) << in.diameter_px;
  EXPECT_EQ(out.flags, in.flags);
}

TEST(MsgMarkWord, RandomMarksRoundTripWithinQuantisation) {
  std::mt19937_64 rng(1);
  for (int i = 0; i < 100000; ++i) {
    const MarkObservation in = test::random_mark(rng);
    std::uint64_t word = 0;
    ASSERT_TRUE(pack_mark(in, word));
    MarkObservation out;
    ASSERT_TRUE(unpack_mark(word, out));
    expect_mark_quantised(in, out);
    // Decoded values are on the grid: encoding them again gives the same word.
    std::uint64_t again = 0;
    ASSERT_TRUE(pack_mark(out, again));
    ASSERT_EQ(again, word);
  }
}

TEST(MsgMarkWord, FieldsSitWhereTheIcdSaysFromTheMsbDown) {
  MarkObservation m;
  m.x_px = -0.5f + 1000.0f / 256.0f;  // code 1000
  m.y_px = -0.5f + 3.0f / 256.0f;     // code 3
  m.sigma_px = 0.001f * 2.0f;         // 0.001 * 2^(16/16): code 16
  m.peak = 200;
  m.diameter_px = 7.5f;  // code 15
  m.flags = mark_flags::kSaturated | mark_flags::kElongated;
  std::uint64_t word = 0;
  ASSERT_TRUE(pack_mark(m, word));
  const std::uint64_t expected = (std::uint64_t{1000} << 45) | (std::uint64_t{3} << 26) |
                                 (std::uint64_t{16} << 18) | (std::uint64_t{200} << 10) |
                                 (std::uint64_t{15} << 4) | 0x9u;
  EXPECT_EQ(word, expected);
}

TEST(MsgMarkWord, CoordinateLimitsAreRejectedNotWrapped) {
  MarkObservation m = {};
  m.sigma_px = 0.05f;
  std::uint64_t word = 0;
  for (float x : {-0.5f, 0.0f, 1919.5f, 2047.49f}) {
    m.x_px = x;
    EXPECT_TRUE(pack_mark(m, word)) << x;
  }
  for (float x : {-0.51f, 2047.5f, 1e9f, -1e9f, std::numeric_limits<float>::quiet_NaN(),
                  std::numeric_limits<float>::infinity()}) {
    m.x_px = x;
    EXPECT_FALSE(pack_mark(m, word)) << x;
    m.x_px = 10.0f;
    m.y_px = x;
    EXPECT_FALSE(pack_mark(m, word)) << x;
    m.y_px = 0.0f;
  }
  // The all-ones code is reserved: a decoder rejects it.
  MarkObservation out;
  EXPECT_FALSE(
      unpack_mark(mark_observation_word::kXPxMask << mark_observation_word::kXPxShift, out));
  EXPECT_FALSE(
      unpack_mark(mark_observation_word::kYPxMask << mark_observation_word::kYPxShift, out));
}

TEST(MsgMarkWord, SaturatingAndInvalidFields) {
  MarkObservation m = {};
  m.x_px = 5.0f;
  m.y_px = 6.0f;
  std::uint64_t word = 0;
  MarkObservation out;
  m.sigma_px = std::numeric_limits<float>::quiet_NaN();  // unknown -> invalid code -> NaN
  m.peak = 4000;                                         // 16-bit DN above 8 bits saturates
  m.diameter_px = 100.0f;                                // saturates at 31.5
  ASSERT_TRUE(pack_mark(m, word));
  ASSERT_TRUE(unpack_mark(word, out));
  EXPECT_TRUE(std::isnan(out.sigma_px));
  EXPECT_EQ(out.peak, 255);
  EXPECT_FLOAT_EQ(out.diameter_px, 31.5f);
  m.sigma_px = 1e-6f;    // below the first step: clamps to 0.001 px
  m.diameter_px = 0.1f;  // small but known: smallest non-invalid code
  ASSERT_TRUE(pack_mark(m, word));
  ASSERT_TRUE(unpack_mark(word, out));
  EXPECT_FLOAT_EQ(out.sigma_px, 0.001f);
  EXPECT_FLOAT_EQ(out.diameter_px, 0.5f);
  m.flags = 0xFF;  // only the 4 defined bits travel
  ASSERT_TRUE(pack_mark(m, word));
  ASSERT_TRUE(unpack_mark(word, out));
  EXPECT_EQ(out.flags, mark_flags::kAllKnown);
}

TEST(MsgByteOrder, BigEndianOnTheWire) {
  std::array<std::uint8_t, 31> buf{};
  bytes::BigEndianWriter w(buf);
  w.put_u8(0x01);
  w.put_u16(0x0203);
  w.put_u32(0x04050607);
  w.put_u64(0x08090A0B0C0D0E0Full);
  w.put_i16(-2);
  w.put_f32(1.0f);  // IEEE 754: 0x3F800000
  w.put_i64(-1);
  ASSERT_TRUE(w.ok());
  EXPECT_EQ(w.size(), 29u);
  const std::array<std::uint8_t, 31> expected{
      1,    2,    3,    4, 5, 6,    7,    8,    9,    10,   11,   12,   13,   14, 15, 0xFF,
      0xFE, 0x3F, 0x80, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0,  0};
  for (std::size_t i = 0; i + 2 < buf.size(); ++i)
    EXPECT_EQ(buf[i], expected[i]) << i;
  w.put_u32(1);  // does not fit
  EXPECT_FALSE(w.ok());

  bytes::BigEndianReader r(buf);
  EXPECT_EQ(r.get_u8(), 0x01);
  EXPECT_EQ(r.get_u16(), 0x0203);
  EXPECT_EQ(r.get_u32(), 0x04050607u);
  EXPECT_EQ(r.get_u64(), 0x08090A0B0C0D0E0Full);
  EXPECT_EQ(r.get_i16(), -2);
  EXPECT_EQ(r.get_f32(), 1.0f);
  EXPECT_EQ(r.get_i64(), -1);
  EXPECT_TRUE(r.ok());
  EXPECT_EQ(r.get_u32(), 0u);  // runs past the end: 0 and a sticky error
  EXPECT_FALSE(r.ok());
}

TEST(MsgCrc32, MatchesTheIeeeCheckValue) {
  const char* text = "123456789";
  const std::span<const std::uint8_t> bytes(reinterpret_cast<const std::uint8_t*>(text), 9);
  EXPECT_EQ(crc32(bytes), 0xCBF43926u);  // CRC-32/ISO-HDLC check value
  EXPECT_EQ(crc32(bytes.subspan(4), crc32(bytes.first(4))), 0xCBF43926u);  // incremental
  EXPECT_EQ(crc32({}), 0u);
}

}  // namespace
}  // namespace storetrack::msg
