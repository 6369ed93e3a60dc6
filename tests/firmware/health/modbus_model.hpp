// What a correct Modbus TCP server of the unit answers, from the protocol (Modbus Application
// Protocol V1.1b3, Modbus Messaging on TCP/IP V1.0b) and docs/modbus.md, written independently
// of firmware/health/src/modbus_server.cpp: the framing of a byte stream into requests, the
// exact reply to each, the holding registers after it, and the counters it must bump. Used by
// the live-server tests (test_modbus.cpp) and the request-path fuzzer (fuzz_modbus_request).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "storetrack/health/register_map.hpp"
#include "storetrack/health/unit_state.hpp"

namespace storetrack::health::model {

inline constexpr std::size_t kMbapBytes = 7;      // transaction, protocol, length, unit id
inline constexpr std::size_t kMaxAduBytes = 260;  // MBAP + the largest PDU (253 bytes)

/// A byte stream as the server must split it: whole requests in order, then either the end,
/// an incomplete request (no reply, the connection stays until it closes), or a header that
/// is not Modbus TCP (protocol id not 0, a length below 2 or past 260 bytes: the connection is
/// closed without a reply).
struct Framing {
  std::vector<std::span<const std::uint8_t>> requests;
  bool bad_header = false;
  std::size_t used = 0;  ///< bytes up to the last whole request (or through the bad header)
};

inline Framing frame_stream(std::span<const std::uint8_t> s) {
  Framing f;
  std::size_t at = 0;
  while (s.size() - at >= kMbapBytes) {
    const std::size_t length = std::size_t{s[at + 4]} << 8 | s[at + 5];
    if (s[at + 2] != 0 || s[at + 3] != 0 || length < 2 || 6 + length > kMaxAduBytes) {
      f.bad_header = true;
      f.used = at + kMbapBytes;
      return f;
    }
    if (s.size() - at < 6 + length) break;
    f.requests.push_back(s.subspan(at, 6 + length));
    at += 6 + length;
  }
  f.used = at;
  return f;
}

struct Counts {
  std::uint64_t requests = 0, refused_function = 0, refused_write_locked = 0, refused_value = 0,
                malformed = 0, writes_accepted = 0, refused_identity = 0;
};

struct Reply {
  std::vector<std::uint8_t> bytes;
  /// Bytes not predictable (the uptime registers of an input read): [from, to).
  std::size_t unknown_from = 0, unknown_to = 0;
};

class Server {
 public:
  using Holding = std::array<std::uint16_t, 10>;  // address order

  Server(bool maintenance, HoldingLimits limits, Holding holding, std::uint32_t generation)
      : maintenance_(maintenance), limits_(limits), holding_(holding), generation_(generation) {}

  const Holding& holding() const { return holding_; }
  const Counts& counts() const { return counts_; }
  std::uint32_t generation() const { return generation_; }

  /// The reply to one whole request (from frame_stream); applies an accepted write.
  Reply answer(std::span<const std::uint8_t> q) {
    ++counts_.requests;
    const std::uint8_t fc = q[7];
    const std::span<const std::uint8_t> pdu = q.subspan(7);
    const auto u16 = [&](std::size_t i) {
      return static_cast<std::uint16_t>(pdu[i] << 8 | pdu[i + 1]);
    };
    switch (fc) {
      case 0x03:
      case 0x04: {
        if (pdu.size() != 5 || u16(3) < 1 || u16(3) > 125) {  // implied length, quantity
          ++counts_.malformed;
          return exception(q, 0x03);
        }
        const std::size_t address = u16(1), count = u16(3);
        const std::size_t size = fc == 0x03 ? holding_.size() : kInputRegisters;
        if (address + count > size) {
          ++counts_.refused_value;
          return exception(q, 0x02);
        }
        Reply r = header(q, 2 + 2 * count);
        r.bytes.push_back(fc);
        r.bytes.push_back(static_cast<std::uint8_t>(2 * count));
        const auto inputs = input_registers();
        for (std::size_t a = address; a < address + count; ++a) {
          const std::uint16_t v = fc == 0x03 ? holding_[a] : inputs[a];
          if (fc == 0x04 && a < 2) {  // uptime_s
            if (r.unknown_to == 0) r.unknown_from = r.bytes.size();
            r.unknown_to = r.bytes.size() + 2;
          }
          r.bytes.push_back(static_cast<std::uint8_t>(v >> 8));
          r.bytes.push_back(static_cast<std::uint8_t>(v & 0xFF));
        }
        return r;
      }
      case 0x06:
      case 0x10: {
        std::vector<std::uint16_t> values;
        bool well_formed = false;
        if (fc == 0x06 && pdu.size() == 5) {
          values.push_back(u16(3));
          well_formed = true;
        } else if (fc == 0x10 && pdu.size() >= 6) {
          const std::size_t count = u16(3);
          well_formed =
              count >= 1 && count <= 123 && pdu[5] == 2 * count && pdu.size() == 6 + 2 * count;
          for (std::size_t k = 0; well_formed && k < count; ++k)
            values.push_back(u16(6 + 2 * k));
        }
        if (!well_formed) {
          ++counts_.malformed;
          return exception(q, 0x03);
        }
        if (!maintenance_) {
          ++counts_.refused_write_locked;
          return exception(q, 0x04);
        }
        const int verdict = judge_write(u16(1), values);
        if (verdict == 0x06) {
          ++counts_.refused_identity;
          return exception(q, 0x06);
        }
        if (verdict != 0) {
          ++counts_.refused_value;
          return exception(q, static_cast<std::uint8_t>(verdict));
        }
        for (std::size_t k = 0; k < values.size(); ++k)
          holding_[u16(1) + k] = values[k];
        ++generation_;
        ++counts_.writes_accepted;
        Reply r = header(q, 5);
        r.bytes.insert(r.bytes.end(), pdu.begin(), pdu.begin() + 5);  // fc, address, value/count
        return r;
      }
      default:
        ++counts_.refused_function;
        return exception(q, 0x01);
    }
  }

 private:
  static constexpr std::size_t kInputRegisters = 32;  // docs/modbus.md: 0..31

  // 0 (accepted), or the exception: 0x02 a register outside the map, 0x03 a value outside its
  // range or a broken cross-register rule (docs/modbus.md), 0x06 an identity change.
  int judge_write(std::size_t address, const std::vector<std::uint16_t>& values) const {
    if (address + values.size() > holding_.size()) return 0x02;
    Holding after = holding_;
    for (std::size_t k = 0; k < values.size(); ++k) {
      const RegisterDef* d =
          find_register(RegisterKind::kHolding, static_cast<std::uint16_t>(address + k));
      if (values[k] < d->min || values[k] > d->max) return 0x03;
      after[address + k] = values[k];
    }
    const long exposure_us = after[2], rate_hz = after[3], pulse_us = after[4];
    if (pulse_us * rate_hz >= 900'000 || exposure_us * rate_hz >= 1'000'000) return 0x03;
    const auto fits = [](long origin, long size, long frame) {
      return frame <= 0 || (origin < frame && origin + size <= frame);
    };
    if (!fits(after[6], after[8], limits_.frame_width) ||
        !fits(after[7], after[9], limits_.frame_height))
      return 0x03;
    if (after[0] != holding_[0] || after[1] != holding_[1]) return 0x06;  // identity locked
    return 0;
  }

  // A unit whose counters are all zero (the fuzzer's and the tests' servers).
  std::array<std::uint16_t, kInputRegisters> input_registers() const {
    std::array<std::uint16_t, kInputRegisters> r{};
    r[23] = r[24] = 0x8000;  // temperatures absent: INT16_MIN
    r[25] = 0x8000;          // ptp_offset_ns unknown: INT32_MIN
    r[26] = 0x0000;
    r[28] = kFirmwareVersion;
    r[29] = static_cast<std::uint16_t>(generation_ & 0xFFFF);
    return r;
  }

  static Reply header(std::span<const std::uint8_t> q, std::size_t pdu_bytes) {
    Reply r;
    const std::size_t length = 1 + pdu_bytes;  // unit id + PDU
    r.bytes = {q[0],
               q[1],
               0,
               0,
               static_cast<std::uint8_t>(length >> 8),
               static_cast<std::uint8_t>(length & 0xFF),
               q[6]};
    return r;
  }

  static Reply exception(std::span<const std::uint8_t> q, std::uint8_t code) {
    Reply r = header(q, 2);
    r.bytes.push_back(static_cast<std::uint8_t>(q[7] | 0x80));
    r.bytes.push_back(code);
    return r;
  }

  bool maintenance_;
  HoldingLimits limits_;
  Holding holding_;
  std::uint32_t generation_;
  Counts counts_;
};

/// True when `got` is the reply `want` (its unpredictable bytes aside).
inline bool same_reply(std::span<const std::uint8_t> got, const Reply& want) {
  if (got.size() != want.bytes.size()) return false;
  for (std::size_t i = 0; i < got.size(); ++i)
    if ((i < want.unknown_from || i >= want.unknown_to) && got[i] != want.bytes[i]) return false;
  return true;
}

}  // namespace storetrack::health::model
