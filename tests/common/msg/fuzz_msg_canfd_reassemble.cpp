// libFuzzer target: the input is a sequence of CAN FD frames (4-byte id, 1-byte len, up to 64
// data bytes, 2-byte time step) pushed into one CanFdReassembler. Any sequence must be handled
// without UB, within the fixed capacity, and every delivered message must re-encode to frames
// that reassemble to the same message.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>

#include "storetrack/msg/canfd_codec.hpp"

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
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static CanFdReassembler* reassembler = nullptr;  // state persists: exercises slot churn
  if (reassembler == nullptr) reassembler = new CanFdReassembler();
  static std::int64_t now = 0;
  std::size_t pos = 0;
  while (pos + 7 <= size) {
    CanFdFrame f;
    f.can_id = static_cast<std::uint32_t>(data[pos]) << 24 |
               static_cast<std::uint32_t>(data[pos + 1]) << 16 |
               static_cast<std::uint32_t>(data[pos + 2]) << 8 | data[pos + 3];
    f.can_id &= 0x3FFFFFFFu;  // mostly 29-bit, sometimes one bit above
    f.len = data[pos + 4];
    now += (static_cast<std::int64_t>(data[pos + 5]) << 8 | data[pos + 6]) * 1000;
    pos += 7;
    const std::size_t avail = std::min<std::size_t>({size - pos, sizeof(f.data), f.len});
    std::memcpy(f.data, data + pos, avail);
    pos += avail;
    std::optional<AnyMessage> done;
    reassembler->push(f, now, done);
    if (done) check_canonical(*done);
    if (reassembler->in_flight() > CanFdReassembler::kSlots) std::abort();
  }
  return 0;
}
