// The byte cursor against byte strings written out by hand from the values' hexadecimal form
// (and IEEE 754 bit patterns), both byte orders, every width; overflow refused without touching
// a byte outside the span.
#include <gtest/gtest.h>

#include <array>
#include <cstdint>
#include <limits>
#include <vector>

#include "storetrack/bytes/byte_cursor.hpp"

namespace storetrack::bytes {
namespace {

using Bytes = std::vector<std::uint8_t>;

// One value of every width and kind, in this order, and its bytes in each order.
template <Endian E>
Bytes write_every_width() {
  Bytes out(64, 0xEE);
  ByteWriter<E> w(out);
  w.put_u8(0xA5);
  w.put_u16(0x0102);
  w.put_u32(0x01020304);
  w.put_u64(0x0102030405060708);
  w.put_i8(-2);                          // 0xFE
  w.put_i16(-2);                         // 0xFFFE
  w.put_i32(-123456789);                 // 0xF8A432EB
  w.put_i64(INT64_MIN);                  // 0x8000000000000000
  w.put_f32(-2.5F);                      // 0xC0200000
  w.put_f64(0.1);                        // 0x3FB999999999999A
  w.put_uint(0x0000A1B2C3D4E5F6ULL, 6);  // 48-bit field
  EXPECT_TRUE(w.ok());
  EXPECT_EQ(w.size(), 1u + 2 + 4 + 8 + 1 + 2 + 4 + 8 + 4 + 8 + 6);
  out.resize(w.size());
  return out;
}

const Bytes kBigEndian = {
    0xA5,                                            // u8
    0x01, 0x02,                                      // u16
    0x01, 0x02, 0x03, 0x04,                          // u32
    0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08,  // u64
    0xFE,                                            // i8
    0xFF, 0xFE,                                      // i16
    0xF8, 0xA4, 0x32, 0xEB,                          // i32
    0x80, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,  // i64
    0xC0, 0x20, 0x00, 0x00,                          // f32
    0x3F, 0xB9, 0x99, 0x99, 0x99, 0x99, 0x99, 0x9A,  // f64
    0xA1, 0xB2, 0xC3, 0xD4, 0xE5, 0xF6,              // 48 bits
};
const Bytes kLittleEndian = {
    0xA5,                                            // u8
    0x02, 0x01,                                      // u16
    0x04, 0x03, 0x02, 0x01,                          // u32
    0x08, 0x07, 0x06, 0x05, 0x04, 0x03, 0x02, 0x01,  // u64
    0xFE,                                            // i8
    0xFE, 0xFF,                                      // i16
    0xEB, 0x32, 0xA4, 0xF8,                          // i32
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x80,  // i64
    0x00, 0x00, 0x20, 0xC0,                          // f32
    0x9A, 0x99, 0x99, 0x99, 0x99, 0x99, 0xB9, 0x3F,  // f64
    0xF6, 0xE5, 0xD4, 0xC3, 0xB2, 0xA1,              // 48 bits
};

TEST(ByteCursor, WritesEveryWidthBigEndian) {
  EXPECT_EQ(write_every_width<Endian::kBig>(), kBigEndian);
}

TEST(ByteCursor, WritesEveryWidthLittleEndian) {
  EXPECT_EQ(write_every_width<Endian::kLittle>(), kLittleEndian);
}

template <Endian E>
void expect_reads_every_width(const Bytes& bytes) {
  ByteReader<E> r(bytes);
  EXPECT_EQ(r.get_u8(), 0xA5);
  EXPECT_EQ(r.get_u16(), 0x0102);
  EXPECT_EQ(r.get_u32(), 0x01020304u);
  EXPECT_EQ(r.get_u64(), 0x0102030405060708u);
  EXPECT_EQ(r.get_i8(), -2);
  EXPECT_EQ(r.get_i16(), -2);
  EXPECT_EQ(r.get_i32(), -123456789);
  EXPECT_EQ(r.get_i64(), INT64_MIN);
  EXPECT_EQ(r.get_f32(), -2.5F);
  EXPECT_EQ(r.get_f64(), 0.1);
  EXPECT_EQ(r.get_uint(6), 0xA1B2C3D4E5F6u);
  EXPECT_TRUE(r.ok());
  EXPECT_EQ(r.position(), bytes.size());
  EXPECT_EQ(r.remaining(), 0u);
}

TEST(ByteCursor, ReadsEveryWidthBigEndian) {
  expect_reads_every_width<Endian::kBig>(kBigEndian);
}

TEST(ByteCursor, ReadsEveryWidthLittleEndian) {
  expect_reads_every_width<Endian::kLittle>(kLittleEndian);
}

TEST(ByteCursor, RawBytesAndZerosKeepTheirOrder) {
  Bytes out(7, 0xEE);
  BigEndianWriter w(out);
  const std::array<std::uint8_t, 3> id = {0x10, 0x20, 0x30};
  w.put_bytes(id);
  w.put_zeros(2);
  EXPECT_TRUE(w.ok());
  EXPECT_EQ(out, (Bytes{0x10, 0x20, 0x30, 0x00, 0x00, 0xEE, 0xEE}));

  LittleEndianReader r(out);
  std::array<std::uint8_t, 3> back{};
  r.get_bytes(back);
  EXPECT_EQ(back, id);
  r.skip(2);
  EXPECT_EQ(r.get_u16(), 0xEEEE);
  EXPECT_TRUE(r.ok());
}

// A write that does not fit leaves every byte it would have touched as it was, marks the cursor
// failed, and every later write is dropped even when it would fit.
TEST(ByteCursor, WriterRefusesOverflowAndStaysFailed) {
  Bytes out(7, 0xEE);
  BigEndianWriter w{std::span(out).first(5)};
  w.put_u16(0x0102);
  w.put_u32(0x03040506);  // 4 > 3 left
  EXPECT_FALSE(w.ok());
  EXPECT_EQ(w.size(), 2u);
  w.put_u8(0x07);  // would fit, but the cursor has failed
  w.put_zeros(1);
  w.put_bytes(std::array<std::uint8_t, 1>{0x08});
  EXPECT_EQ(w.size(), 2u);
  EXPECT_EQ(out, (Bytes{0x01, 0x02, 0xEE, 0xEE, 0xEE, 0xEE, 0xEE}));
}

TEST(ByteCursor, WriterRefusesEveryWidthOneByteShort) {
  for (std::size_t n : {1u, 2u, 4u, 8u}) {
    Bytes out(n, 0xEE);
    LittleEndianWriter w{std::span(out).first(n - 1)};
    w.put_uint(0, n);
    EXPECT_FALSE(w.ok()) << n;
    EXPECT_EQ(out, Bytes(n, 0xEE)) << n;
  }
  Bytes out(16, 0xEE);
  BigEndianWriter wide(out);
  wide.put_uint(0, 9);  // no integer is 9 bytes wide: refused, not a shift past 63
  EXPECT_FALSE(wide.ok());
  EXPECT_EQ(out, Bytes(16, 0xEE));
}

// A read past the end returns 0, moves the reader to its end and fails it; later reads return 0
// even where bytes were left.
TEST(ByteCursor, ReaderRefusesOverrunAndStaysFailed) {
  const Bytes in = {0x01, 0x02, 0x03};
  BigEndianReader r(in);
  EXPECT_EQ(r.get_u16(), 0x0102);
  EXPECT_EQ(r.get_u16(), 0);  // one byte left
  EXPECT_FALSE(r.ok());
  EXPECT_EQ(r.remaining(), 0u);
  EXPECT_EQ(r.get_u8(), 0);

  LittleEndianReader empty(std::span<const std::uint8_t>{});
  EXPECT_EQ(empty.get_u8(), 0);
  EXPECT_FALSE(empty.ok());

  LittleEndianReader wide(in);
  EXPECT_EQ(wide.get_uint(9), 0u);
  EXPECT_FALSE(wide.ok());

  LittleEndianReader bytes(in);
  std::array<std::uint8_t, 4> four{0xEE, 0xEE, 0xEE, 0xEE};
  bytes.get_bytes(four);
  EXPECT_FALSE(bytes.ok());
  EXPECT_EQ(four, (std::array<std::uint8_t, 4>{0, 0, 0, 0}));

  LittleEndianReader skipper(in);
  skipper.skip(4);
  EXPECT_FALSE(skipper.ok());
}

TEST(ByteCursor, ReaderRefusesEveryWidthOneByteShort) {
  const Bytes in(8, 0xFF);
  for (std::size_t n : {1u, 2u, 4u, 8u}) {
    BigEndianReader r{std::span(in).first(n - 1)};
    EXPECT_EQ(r.get_uint(n), 0u) << n;
    EXPECT_FALSE(r.ok()) << n;
  }
}

// NaN keeps its payload bits through the cursor (the wire's invalid value).
TEST(ByteCursor, FloatBitPatternsPass) {
  Bytes out(4);
  BigEndianWriter w(out);
  w.put_f32(std::numeric_limits<float>::quiet_NaN());
  EXPECT_EQ(out, (Bytes{0x7F, 0xC0, 0x00, 0x00}));
}

// Usable in constant expressions (a codec can static_assert a layout with it).
constexpr std::uint16_t little_of(std::uint8_t lo, std::uint8_t hi) {
  const std::array<std::uint8_t, 2> b = {lo, hi};
  LittleEndianReader r(b);
  return r.get_u16();
}
static_assert(little_of(0x25, 0xEB) == 0xEB25);

}  // namespace
}  // namespace storetrack::bytes
