// libFuzzer target for CanFdReassembler. Input byte 0 selects the mode:
//  - even: a sequence of raw frames (4-byte id, 1-byte len, 2-byte time step, up to 64 data
//    bytes) pushed into one long-lived reassembler (slot churn, timeouts, evictions);
//  - odd: the rest is a transfer stream payload; the harness appends its CRC-32 and fragments
//    it like the encoder (id from the first payload bytes), so the payload range checks behind
//    the CRC are reached.
// Any input must be handled without UB and within the fixed capacity, and every delivered
// message must re-encode to frames that reassemble again.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>

#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/msg/canfd_codec.hpp"
#include "storetrack/msg/crc.hpp"

namespace {
using namespace storetrack::msg;

void check_canonical(const AnyMessage& message) {
  CanFdFrame frames[kCanFdMaxFramesPerMessage];
  const int n = std::visit([&](const auto& m) { return encode_canfd(m, frames); }, message);
  if (n <= 0) std::abort();
  CanFdReassembler fresh;
  std::optional<AnyMessage> done;
  for (int i = 0; i < n; ++i) {
    if (fresh.push(frames[i], 0, done) != DecodeError::kNone) std::abort();
  }
  if (!done || done->index() != message.index()) std::abort();
}

void raw_frames(CanFdReassembler& reassembler, std::int64_t& now, const std::uint8_t* data,
                std::size_t size) {
  std::size_t pos = 0;
  while (pos + 7 <= size) {
    CanFdFrame f;
    storetrack::bytes::BigEndianReader r(std::span<const std::uint8_t>(data + pos, 7));
    f.can_id = r.get_u32() & 0x3FFFFFFFu;  // mostly 29 bits, sometimes one bit above
    f.len = r.get_u8();
    now += static_cast<std::int64_t>(r.get_u16()) * 1000;
    pos += 7;
    const std::size_t avail = std::min<std::size_t>({size - pos, sizeof(f.data), f.len});
    std::memcpy(f.data, data + pos, avail);
    pos += avail;
    std::optional<AnyMessage> done;
    reassembler.push(f, now, done);
    if (done) check_canonical(*done);
    if (reassembler.in_flight() > CanFdReassembler::kSlots) std::abort();
  }
}

void structured_transfer(const std::uint8_t* data, std::size_t size) {
  if (size < 2 + kCanFdTransferCrcBytes) return;
  const bool health = (data[0] & 1) != 0;
  std::uint8_t stream[kCanFdMaxFragments * kCanFdFragmentPayloadBytes] = {};
  const std::size_t payload = std::min(size - 1, sizeof(stream) - kCanFdTransferCrcBytes);
  std::memcpy(stream, data + 1, payload);
  storetrack::bytes::BigEndianWriter w(
      std::span<std::uint8_t>(stream + payload, kCanFdTransferCrcBytes));
  w.put_u32(crc32(std::span<const std::uint8_t>(stream, payload)));
  const std::size_t length = payload + kCanFdTransferCrcBytes;
  const std::size_t count = (length + kCanFdFragmentPayloadBytes - 1) / kCanFdFragmentPayloadBytes;
  if (count > kCanFdMaxFragments) return;
  // Ids and sequence as the encoder would derive them from the payload (MarkObservations:
  // unit, camera at bytes 0, 1 and trigger_seq at 2..5; UnitHealth: unit at byte 0 and
  // report_tai_ns at 6..13).
  const std::uint8_t fid = health ? 2 : 1;
  const std::uint32_t id =
      canid::make(canid::kLccNoc, fid, stream[0], health ? 0 : stream[1],
                  canid::message_version(static_cast<storetrack::msg::MessageId>(fid)));
  storetrack::bytes::BigEndianReader health_time(
      std::span<const std::uint8_t>(stream + 6, 8));  // report_tai_ns
  const std::uint16_t seq =
      health ? static_cast<std::uint16_t>(static_cast<std::uint64_t>(health_time.get_i64()) >> 20)
             : static_cast<std::uint16_t>(stream[4] << 8 | stream[5]);
  CanFdReassembler reassembler;
  std::optional<AnyMessage> done;
  for (std::size_t i = 0; i < count; ++i) {
    CanFdFrame f;
    f.can_id = id;
    const std::size_t begin = i * kCanFdFragmentPayloadBytes;
    const std::size_t chunk = std::min(kCanFdFragmentPayloadBytes, length - begin);
    f.len = canfd_round_up_len(kCanFdFragmentHeaderBytes + chunk);
    storetrack::bytes::BigEndianWriter fw(std::span<std::uint8_t>(f.data, f.len));
    fw.put_u16(seq);
    fw.put_u8(static_cast<std::uint8_t>(i << 4 | (count - 1)));
    fw.put_bytes(std::span<const std::uint8_t>(stream + begin, chunk));
    reassembler.push(f, 0, done);
  }
  if (done) check_canonical(*done);
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static CanFdReassembler* reassembler = new CanFdReassembler();  // persists across inputs
  static std::int64_t now = 0;
  if (size == 0) return 0;
  if ((data[0] & 1) != 0) {
    structured_transfer(data + 1, size - 1);
  } else {
    raw_frames(*reassembler, now, data + 1, size - 1);
  }
  return 0;
}
