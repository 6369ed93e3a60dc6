// The ONE place where storetrack converts between host and wire (big-endian) byte order.
// Every encoder writes through BeWriter and every decoder reads through BeReader; nothing else
// in common/msg touches multi-byte integers on the wire. Neither allocates nor throws: a writer
// that runs out of space and a reader that runs past its end set a sticky error flag instead
// (reads then return 0), so a caller checks ok() once after a sequence of operations.
#pragma once

#include <bit>
#include <cstddef>
#include <cstdint>
#include <span>

namespace storetrack::msg {

class BeWriter {
 public:
  explicit BeWriter(std::span<std::uint8_t> out) : out_(out) {}

  void put_u8(std::uint8_t v) { put_be(v, 1); }
  void put_u16(std::uint16_t v) { put_be(v, 2); }
  void put_u32(std::uint32_t v) { put_be(v, 4); }
  void put_u64(std::uint64_t v) { put_be(v, 8); }
  void put_i8(std::int8_t v) { put_u8(static_cast<std::uint8_t>(v)); }
  void put_i16(std::int16_t v) { put_u16(static_cast<std::uint16_t>(v)); }
  void put_i32(std::int32_t v) { put_u32(static_cast<std::uint32_t>(v)); }
  void put_i64(std::int64_t v) { put_u64(static_cast<std::uint64_t>(v)); }
  void put_f32(float v) { put_u32(std::bit_cast<std::uint32_t>(v)); }  // IEEE 754 binary32
  void put_f64(double v) { put_u64(std::bit_cast<std::uint64_t>(v)); }
  void put_bytes(std::span<const std::uint8_t> bytes) {
    if (bytes.size() > remaining()) {
      ok_ = false;
      return;
    }
    for (std::uint8_t b : bytes)
      out_[pos_++] = b;
  }

  std::size_t size() const { return pos_; }  ///< bytes written
  std::size_t remaining() const { return out_.size() - pos_; }
  bool ok() const { return ok_; }

 private:
  void put_be(std::uint64_t v, std::size_t n) {
    if (n > remaining()) {
      ok_ = false;
      return;
    }
    for (std::size_t i = 0; i < n; ++i)
      out_[pos_ + i] = static_cast<std::uint8_t>(v >> (8 * (n - 1 - i)));
    pos_ += n;
  }

  std::span<std::uint8_t> out_;
  std::size_t pos_ = 0;
  bool ok_ = true;
};

class BeReader {
 public:
  explicit BeReader(std::span<const std::uint8_t> in) : in_(in) {}

  std::uint8_t get_u8() { return static_cast<std::uint8_t>(get_be(1)); }
  std::uint16_t get_u16() { return static_cast<std::uint16_t>(get_be(2)); }
  std::uint32_t get_u32() { return static_cast<std::uint32_t>(get_be(4)); }
  std::uint64_t get_u64() { return get_be(8); }
  std::int8_t get_i8() { return static_cast<std::int8_t>(get_u8()); }
  std::int16_t get_i16() { return static_cast<std::int16_t>(get_u16()); }
  std::int32_t get_i32() { return static_cast<std::int32_t>(get_u32()); }
  std::int64_t get_i64() { return static_cast<std::int64_t>(get_u64()); }
  float get_f32() { return std::bit_cast<float>(get_u32()); }
  double get_f64() { return std::bit_cast<double>(get_u64()); }

  std::size_t position() const { return pos_; }
  std::size_t remaining() const { return in_.size() - pos_; }
  bool ok() const { return ok_; }

 private:
  std::uint64_t get_be(std::size_t n) {
    if (n > remaining()) {
      ok_ = false;
      pos_ = in_.size();
      return 0;
    }
    std::uint64_t v = 0;
    for (std::size_t i = 0; i < n; ++i)
      v = (v << 8) | in_[pos_ + i];
    pos_ += n;
    return v;
  }

  std::span<const std::uint8_t> in_;
  std::size_t pos_ = 0;
  bool ok_ = true;
};

}  // namespace storetrack::msg
