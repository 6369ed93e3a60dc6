// The one place where PTP's network byte order (big-endian, IEEE 1588-2008 5.3) meets host
// integers: every field of a management message is read or written through these two cursors.
// Reads past the end return 0 and mark the cursor failed, so a short reply is a checked
// condition, never an out-of-bounds access.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

namespace storetrack::clock::detail {

class BigEndianReader {
 public:
  explicit BigEndianReader(std::span<const std::uint8_t> bytes) : bytes_(bytes) {}

  std::uint64_t unsigned_bytes(std::size_t n) {
    if (failed_ || bytes_.size() - offset_ < n) {
      failed_ = true;
      return 0;
    }
    std::uint64_t v = 0;
    for (std::size_t i = 0; i < n; ++i)
      v = (v << 8) | bytes_[offset_ + i];
    offset_ += n;
    return v;
  }
  std::uint8_t u8() { return static_cast<std::uint8_t>(unsigned_bytes(1)); }
  std::uint16_t u16() { return static_cast<std::uint16_t>(unsigned_bytes(2)); }
  std::uint32_t u32() { return static_cast<std::uint32_t>(unsigned_bytes(4)); }
  std::uint64_t u64() { return unsigned_bytes(8); }
  // Two's complement on the wire and in the host (C++20): the casts keep the bit pattern.
  std::int8_t i8() { return static_cast<std::int8_t>(u8()); }
  std::int16_t i16() { return static_cast<std::int16_t>(u16()); }
  std::int32_t i32() { return static_cast<std::int32_t>(u32()); }
  std::int64_t i64() { return static_cast<std::int64_t>(u64()); }
  template <std::size_t N>
  void copy(std::array<std::uint8_t, N>& out) {
    for (auto& b : out)
      b = u8();
  }
  void skip(std::size_t n) {
    if (failed_ || bytes_.size() - offset_ < n) {
      failed_ = true;
      return;
    }
    offset_ += n;
  }
  bool failed() const { return failed_; }
  std::size_t offset() const { return offset_; }

 private:
  std::span<const std::uint8_t> bytes_;
  std::size_t offset_ = 0;
  bool failed_ = false;
};

class BigEndianWriter {
 public:
  explicit BigEndianWriter(std::span<std::uint8_t> bytes) : bytes_(bytes) {}

  void unsigned_bytes(std::uint64_t v, std::size_t n) {
    if (failed_ || bytes_.size() - offset_ < n) {
      failed_ = true;
      return;
    }
    for (std::size_t i = 0; i < n; ++i)
      bytes_[offset_ + i] = static_cast<std::uint8_t>(v >> (8 * (n - 1 - i)));
    offset_ += n;
  }
  void u8(std::uint8_t v) { unsigned_bytes(v, 1); }
  void u16(std::uint16_t v) { unsigned_bytes(v, 2); }
  void u32(std::uint32_t v) { unsigned_bytes(v, 4); }
  void u64(std::uint64_t v) { unsigned_bytes(v, 8); }
  void zeros(std::size_t n) {
    for (std::size_t i = 0; i < n; ++i)
      u8(0);
  }
  bool failed() const { return failed_; }
  std::size_t offset() const { return offset_; }

 private:
  std::span<std::uint8_t> bytes_;
  std::size_t offset_ = 0;
  bool failed_ = false;
};

}  // namespace storetrack::clock::detail
