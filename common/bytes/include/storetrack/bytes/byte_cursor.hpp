// The ONE place where storetrack converts between host integers and wire byte order. Every codec
// reads and writes multi-byte fields through these cursors: big-endian for the unit's messages,
// PTP management (IEEE 1588-2008 5.3), iNET-X and the FTI parameter block; little-endian for the
// IRIG 106 Chapter 10 packet structure. Nothing else in the tree shifts bytes of a wire integer.
//
// A cursor walks a caller's span. It never allocates or throws (it runs on the unit's per-frame
// path): a write that does not fit and a read past the end mark the cursor failed, and from then
// on every write is dropped and every read returns 0, so a caller checks ok() once after a
// sequence of fields. No access ever leaves the span.
#pragma once

#include <bit>
#include <cstddef>
#include <cstdint>
#include <span>

namespace storetrack::bytes {

enum class Endian : std::uint8_t { kBig, kLittle };

/// Writes fields one after another into `out`, in the byte order E.
template <Endian E>
class ByteWriter {
 public:
  constexpr explicit ByteWriter(std::span<std::uint8_t> out) : out_(out) {}

  /// The low `n` (1..8) bytes of `v`: for fields that are not a whole C++ integer (48-bit RTC).
  constexpr void put_uint(std::uint64_t v, std::size_t n) {
    if (!reserve(n > 8 ? remaining() + 1 : n)) return;  // wider than 8: refused like overflow
    for (std::size_t i = 0; i < n; ++i)
      out_[pos_ + i] = static_cast<std::uint8_t>(v >> shift_of(i, n));
    pos_ += n;
  }
  constexpr void put_u8(std::uint8_t v) { put_uint(v, 1); }
  constexpr void put_u16(std::uint16_t v) { put_uint(v, 2); }
  constexpr void put_u32(std::uint32_t v) { put_uint(v, 4); }
  constexpr void put_u64(std::uint64_t v) { put_uint(v, 8); }
  // Two's complement in the host and on the wire (C++20): the casts keep the bit pattern.
  constexpr void put_i8(std::int8_t v) { put_u8(static_cast<std::uint8_t>(v)); }
  constexpr void put_i16(std::int16_t v) { put_u16(static_cast<std::uint16_t>(v)); }
  constexpr void put_i32(std::int32_t v) { put_u32(static_cast<std::uint32_t>(v)); }
  constexpr void put_i64(std::int64_t v) { put_u64(static_cast<std::uint64_t>(v)); }
  /// IEEE 754 binary32 / binary64, bit pattern in the cursor's byte order.
  constexpr void put_f32(float v) { put_u32(std::bit_cast<std::uint32_t>(v)); }
  constexpr void put_f64(double v) { put_u64(std::bit_cast<std::uint64_t>(v)); }
  /// Bytes as they are (no byte order: identities, text, an already-encoded block).
  constexpr void put_bytes(std::span<const std::uint8_t> bytes) {
    if (!reserve(bytes.size())) return;
    for (std::size_t i = 0; i < bytes.size(); ++i)
      out_[pos_ + i] = bytes[i];
    pos_ += bytes.size();
  }
  constexpr void put_zeros(std::size_t n) {
    if (!reserve(n)) return;
    for (std::size_t i = 0; i < n; ++i)
      out_[pos_ + i] = 0;
    pos_ += n;
  }

  constexpr std::size_t size() const { return pos_; }  ///< bytes written
  constexpr std::size_t remaining() const { return out_.size() - pos_; }
  constexpr bool ok() const { return ok_; }

 private:
  static constexpr unsigned shift_of(std::size_t i, std::size_t n) {
    return static_cast<unsigned>(8 * (E == Endian::kBig ? n - 1 - i : i));
  }
  constexpr bool reserve(std::size_t n) {
    if (ok_ && n <= remaining()) return true;
    ok_ = false;
    return false;
  }

  std::span<std::uint8_t> out_;
  std::size_t pos_ = 0;
  bool ok_ = true;
};

/// Reads fields one after another from `in`, in the byte order E.
template <Endian E>
class ByteReader {
 public:
  constexpr explicit ByteReader(std::span<const std::uint8_t> in) : in_(in) {}

  /// `n` (1..8) bytes as an unsigned integer (48-bit RTC and the like).
  constexpr std::uint64_t get_uint(std::size_t n) {
    if (!take(n > 8 ? remaining() + 1 : n)) return 0;  // wider than 8: refused like a short read
    std::uint64_t v = 0;
    for (std::size_t i = 0; i < n; ++i)
      v |= std::uint64_t{in_[pos_ + i]} << shift_of(i, n);
    pos_ += n;
    return v;
  }
  constexpr std::uint8_t get_u8() { return static_cast<std::uint8_t>(get_uint(1)); }
  constexpr std::uint16_t get_u16() { return static_cast<std::uint16_t>(get_uint(2)); }
  constexpr std::uint32_t get_u32() { return static_cast<std::uint32_t>(get_uint(4)); }
  constexpr std::uint64_t get_u64() { return get_uint(8); }
  constexpr std::int8_t get_i8() { return static_cast<std::int8_t>(get_u8()); }
  constexpr std::int16_t get_i16() { return static_cast<std::int16_t>(get_u16()); }
  constexpr std::int32_t get_i32() { return static_cast<std::int32_t>(get_u32()); }
  constexpr std::int64_t get_i64() { return static_cast<std::int64_t>(get_u64()); }
  constexpr float get_f32() { return std::bit_cast<float>(get_u32()); }
  constexpr double get_f64() { return std::bit_cast<double>(get_u64()); }
  /// Fills `out` with the next bytes as they are; zeros when they are not all there.
  constexpr void get_bytes(std::span<std::uint8_t> out) {
    const bool there = take(out.size());
    for (std::size_t i = 0; i < out.size(); ++i)
      out[i] = there ? in_[pos_ + i] : 0;
    if (there) pos_ += out.size();
  }
  constexpr void skip(std::size_t n) {
    if (take(n)) pos_ += n;
  }

  constexpr std::size_t position() const { return pos_; }  ///< bytes read (or skipped)
  constexpr std::size_t remaining() const { return in_.size() - pos_; }
  constexpr bool ok() const { return ok_; }

 private:
  static constexpr unsigned shift_of(std::size_t i, std::size_t n) {
    return static_cast<unsigned>(8 * (E == Endian::kBig ? n - 1 - i : i));
  }
  constexpr bool take(std::size_t n) {
    if (ok_ && n <= remaining()) return true;
    ok_ = false;
    pos_ = in_.size();  // a failed reader stays at its end
    return false;
  }

  std::span<const std::uint8_t> in_;
  std::size_t pos_ = 0;
  bool ok_ = true;
};

using BigEndianWriter = ByteWriter<Endian::kBig>;
using BigEndianReader = ByteReader<Endian::kBig>;
using LittleEndianWriter = ByteWriter<Endian::kLittle>;
using LittleEndianReader = ByteReader<Endian::kLittle>;

}  // namespace storetrack::bytes
