#include "storetrack/msg/canfd_codec.hpp"

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cstring>
#include <string_view>

#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/msg/crc.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::msg {
namespace {

constexpr std::size_t frames_for_stream(std::size_t stream_bytes) {
  return (stream_bytes + kCanFdFragmentPayloadBytes - 1) / kCanFdFragmentPayloadBytes;
}
constexpr std::size_t kMaxMarkFrames =
    frames_for_stream(kMarkObservationsMaxPayloadBytes + kCanFdTransferCrcBytes);
constexpr std::size_t kMaxHealthFrames =
    frames_for_stream(kUnitHealthMaxPayloadBytes + kCanFdTransferCrcBytes);
static_assert(kMaxMarkFrames <= kCanFdMaxFragments && kMaxHealthFrames <= kCanFdMaxFragments);

// The transfer length of MarkObservations follows from mark_count, found through the schema's
// field table so that a schema change cannot silently break the reassembler.
constexpr std::size_t field_offset(std::string_view name) {
  for (const FieldInfo& f : kMarkObservationsFields)
    if (f.name == name) return f.offset;
  return kMarkObservationsFixedBytes;
}
constexpr std::size_t kMarkCountOffset = field_offset("mark_count");
static_assert(kMarkCountOffset < kMarkObservationsFixedBytes, "schema lacks mark_count");

constexpr std::uint8_t kValidLens[] = {0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64};

bool is_valid_canfd_len(std::uint8_t len) {
  return std::find(std::begin(kValidLens), std::end(kValidLens), len) != std::end(kValidLens);
}

std::uint16_t transfer_seq(const MarkObservations& m) {
  return static_cast<std::uint16_t>(m.trigger_seq & 0xFFFFu);
}
// Health has no sequence number: its report time in units of 2^20 ns (~1.05 ms) is unique per
// report and wraps after ~69 s, far beyond the reassembly timeout.
std::uint16_t transfer_seq(const UnitHealth& m) {
  return static_cast<std::uint16_t>((static_cast<std::uint64_t>(m.report_tai_ns) >> 20) & 0xFFFFu);
}
std::uint8_t camera_of(const MarkObservations& m) {
  return m.camera_id;
}
std::uint8_t camera_of(const UnitHealth&) {
  return 0;
}

template <typename Message>
int encode(const Message& m, MessageId id, std::span<CanFdFrame> out) {
  std::array<std::uint8_t, kCanFdMaxTransferBytes> stream;
  bytes::BigEndianWriter w(stream);
  if (const int rc = pack_payload(m, w); rc != 0) return rc;
  w.put_u32(crc32(std::span<const std::uint8_t>(stream).first(w.size())));
  if (!w.ok()) return -ENOSPC;
  const std::size_t length = w.size();
  const std::size_t count = frames_for_stream(length);
  if (count > kCanFdMaxFragments) return -ERANGE;
  if (out.size() < count) return -ENOSPC;
  const std::uint32_t can_id = canid::make(canid::kLccNoc, static_cast<std::uint8_t>(id), m.unit_id,
                                           camera_of(m), canid::message_version(id));
  for (std::size_t i = 0; i < count; ++i) {
    CanFdFrame& f = out[i];
    const std::size_t begin = i * kCanFdFragmentPayloadBytes;
    const std::size_t chunk = std::min(kCanFdFragmentPayloadBytes, length - begin);
    f.can_id = can_id;
    f.len = canfd_round_up_len(kCanFdFragmentHeaderBytes + chunk);
    std::memset(f.data, 0, sizeof(f.data));
    bytes::BigEndianWriter fw(std::span<std::uint8_t>(f.data, f.len));
    fw.put_u16(transfer_seq(m));
    fw.put_u8(static_cast<std::uint8_t>(i << 4 | (count - 1)));
    fw.put_bytes(std::span<const std::uint8_t>(stream).subspan(begin, chunk));
  }
  return static_cast<int>(count);
}

template <typename Message>
std::size_t frame_count(const Message& m) {
  return frames_for_stream(payload_size(m) + kCanFdTransferCrcBytes);
}

}  // namespace

std::uint8_t canfd_round_up_len(std::size_t n) {
  for (std::uint8_t len : kValidLens)
    if (len >= n) return len;
  return 64;
}

std::size_t canfd_frame_count(const MarkObservations& m) {
  return frame_count(m);
}
std::size_t canfd_frame_count(const UnitHealth& m) {
  return frame_count(m);
}

int encode_canfd(const MarkObservations& m, std::span<CanFdFrame> out) {
  return encode(m, MessageId::kMarkObservations, out);
}
int encode_canfd(const UnitHealth& m, std::span<CanFdFrame> out) {
  return encode(m, MessageId::kUnitHealth, out);
}

// ---------------------------------------------------------------------------------------------
CanFdReassembler::CanFdReassembler(const CanReassemblerConfig& config) : config_(config) {}

std::size_t CanFdReassembler::in_flight() const {
  return static_cast<std::size_t>(
      std::count_if(slots_.begin(), slots_.end(), [](const Slot& s) { return s.used; }));
}

DecodeError CanFdReassembler::count_error(DecodeError e) {
  switch (e) {
    case DecodeError::kNone:
      break;
    case DecodeError::kBadMagic:
      ++counters_.not_ours;
      break;
    case DecodeError::kBadVersion:
      ++counters_.bad_version;
      break;
    case DecodeError::kTooShort:
    case DecodeError::kBadLength:
      ++counters_.bad_length;
      break;
    case DecodeError::kBadCrc:
      ++counters_.crc_errors;
      break;
    case DecodeError::kUnknownType:
      ++counters_.unknown_type;
      break;
    case DecodeError::kOutOfRange:
      ++counters_.out_of_range;
      break;
  }
  return e;
}

void CanFdReassembler::release(Slot& slot, bool lost) {
  if (lost) {
    counters_.fragments_lost +=
        static_cast<std::uint64_t>(slot.count - std::popcount(slot.received_mask));
  }
  slot.used = false;
  slot.received_mask = 0;
}

void CanFdReassembler::expire(std::int64_t now_ns) {
  for (Slot& slot : slots_) {
    if (slot.used && now_ns - slot.first_ns > config_.timeout_ns) {
      ++counters_.timeouts;
      release(slot, true);
    }
  }
}

DecodeError CanFdReassembler::push(const CanFdFrame& frame, std::optional<AnyMessage>& completed) {
  return push(frame, time::monotonic_now_ns(), completed);
}

DecodeError CanFdReassembler::push(const CanFdFrame& frame, std::int64_t now_ns,
                                   std::optional<AnyMessage>& completed) {
  completed.reset();
  finished_ = false;
  ++counters_.frames;
  expire(now_ns);
  // ---- frame checks: everything needed before the frame may touch a slot ----
  const std::uint32_t id = frame.can_id;
  if (id > canid::kMask29 || canid::lcc(id) != canid::kLccNoc)
    return count_error(DecodeError::kBadMagic);
  std::size_t max_frames = 0;
  switch (static_cast<MessageId>(canid::fid(id))) {
    case MessageId::kMarkObservations:
      max_frames = kMaxMarkFrames;
      break;
    case MessageId::kUnitHealth:
      if (canid::camera(id) != 0) return count_error(DecodeError::kOutOfRange);
      max_frames = kMaxHealthFrames;
      break;
    default:
      return count_error(DecodeError::kUnknownType);
  }
  if (canid::version(id) != canid::message_version(static_cast<MessageId>(canid::fid(id))))
    return count_error(DecodeError::kBadVersion);  // an older unit's layout: refused, counted
  if (frame.len <= kCanFdFragmentHeaderBytes) return count_error(DecodeError::kTooShort);
  if (frame.len > kCanFdMaxData || !is_valid_canfd_len(frame.len))
    return count_error(DecodeError::kBadLength);
  bytes::BigEndianReader r(std::span<const std::uint8_t>(frame.data, frame.len));
  const Key key{id, r.get_u16()};
  const std::uint8_t fragment = r.get_u8();
  const std::size_t index = fragment >> 4;
  const std::size_t count = (fragment & 0x0Fu) + 1u;
  if (index >= count || count > max_frames) return count_error(DecodeError::kBadLength);
  const bool last = index + 1 == count;
  if (!last && frame.len != kCanFdMaxData) return count_error(DecodeError::kBadLength);

  // ---- duplicates of transfers already delivered (or rejected) ----
  // (only within one timeout: a later transfer may legitimately reuse the 16-bit sequence)
  for (std::size_t i = 0; i < recent_size_; ++i) {
    if (recent_[i].key == key && now_ns - recent_[i].done_ns <= config_.timeout_ns) {
      ++counters_.duplicates;
      return DecodeError::kNone;
    }
  }
  // ---- find or open the slot ----
  Slot* slot = nullptr;
  Slot* free_slot = nullptr;
  Slot* oldest = &slots_[0];
  for (Slot& s : slots_) {
    if (s.used && s.key == key) {
      slot = &s;
      break;
    }
    if (!s.used && free_slot == nullptr) free_slot = &s;
    if (s.used && (!oldest->used || s.first_ns < oldest->first_ns)) oldest = &s;
  }
  if (slot == nullptr) {
    if (free_slot == nullptr) {
      ++counters_.evictions;
      release(*oldest, true);
      free_slot = oldest;
    }
    slot = free_slot;
    slot->used = true;
    slot->key = key;
    slot->count = static_cast<std::uint8_t>(count);
    slot->received_mask = 0;
    slot->last_len = 0;
    slot->first_ns = now_ns;
  } else if (slot->count != count) {
    return count_error(DecodeError::kBadLength);  // conflicting fragment counts: keep the first
  }
  const std::uint16_t bit = static_cast<std::uint16_t>(1u << index);
  if (slot->received_mask & bit) {
    ++counters_.duplicates;
    return DecodeError::kNone;
  }
  const std::size_t chunk = frame.len - kCanFdFragmentHeaderBytes;
  std::memcpy(slot->stream.data() + index * kCanFdFragmentPayloadBytes,
              frame.data + kCanFdFragmentHeaderBytes, chunk);
  if (last) slot->last_len = static_cast<std::uint8_t>(chunk);
  slot->received_mask |= bit;
  ++counters_.fragments_accepted;
  if (slot->received_mask != (1u << count) - 1u) return DecodeError::kNone;
  return finish(*slot, now_ns, completed);
}

DecodeError CanFdReassembler::finish(Slot& slot, std::int64_t now_ns,
                                     std::optional<AnyMessage>& completed) {
  recent_[recent_next_] = RecentKey{slot.key, now_ns};
  recent_next_ = (recent_next_ + 1) % kRecentKeys;
  recent_size_ = std::min(recent_size_ + 1, kRecentKeys);
  const Key key = slot.key;
  const std::size_t count = slot.count;
  const std::size_t available = (count - 1) * kCanFdFragmentPayloadBytes + slot.last_len;
  const std::span<const std::uint8_t> stream(slot.stream.data(), available);
  release(slot, false);  // the stream stays readable until the next push
  finished_ = true;
  finished_transfer_ = FinishedTransfer{key.can_id, stream};

  // The transfer's shape: the fragment count and the last frame's DLC must be exactly what the
  // encoder produces for the length its content gives. Then its content (decode_canfd_stream).
  const bool marks =
      canid::fid(key.can_id) == static_cast<std::uint8_t>(MessageId::kMarkObservations);
  std::size_t payload_bytes = kUnitHealthFixedBytes;
  if (marks) {
    if (available <= kMarkCountOffset) return count_error(DecodeError::kBadLength);
    const std::size_t mark_count = stream[kMarkCountOffset];
    if (mark_count > kMaxMarks) return count_error(DecodeError::kOutOfRange);
    payload_bytes = kMarkObservationsFixedBytes + mark_count * kMarkObservationBytes;
  }
  const std::size_t length = payload_bytes + kCanFdTransferCrcBytes;
  if (frames_for_stream(length) != count) return count_error(DecodeError::kBadLength);
  const std::size_t last_chunk = length - (count - 1) * kCanFdFragmentPayloadBytes;
  if (canfd_round_up_len(kCanFdFragmentHeaderBytes + last_chunk) !=
      kCanFdFragmentHeaderBytes + slot.last_len)
    return count_error(DecodeError::kBadLength);
  AnyMessage message;
  DecodeError e = decode_canfd_stream(key.can_id, stream, message);
  if (e == DecodeError::kNone) {
    const auto* marks_message = std::get_if<MarkObservations>(&message);
    const std::uint16_t seq =
        marks_message ? transfer_seq(*marks_message) : transfer_seq(std::get<UnitHealth>(message));
    if (seq != key.seq) e = DecodeError::kOutOfRange;
  }
  if (e != DecodeError::kNone) {
    completed.reset();
    return count_error(e);
  }
  completed = std::move(message);
  ++counters_.completed;
  return DecodeError::kNone;
}

DecodeError decode_canfd_stream(std::uint32_t can_id, std::span<const std::uint8_t> stream,
                                AnyMessage& out) {
  const bool marks = canid::fid(can_id) == static_cast<std::uint8_t>(MessageId::kMarkObservations);
  std::size_t payload_bytes = kUnitHealthFixedBytes;
  if (marks) {
    if (stream.size() <= kMarkCountOffset) return DecodeError::kBadLength;
    const std::size_t mark_count = stream[kMarkCountOffset];
    if (mark_count > kMaxMarks) return DecodeError::kOutOfRange;
    payload_bytes = kMarkObservationsFixedBytes + mark_count * kMarkObservationBytes;
  }
  if (stream.size() < payload_bytes + kCanFdTransferCrcBytes) return DecodeError::kBadLength;
  bytes::BigEndianReader crc_reader(stream.subspan(payload_bytes, kCanFdTransferCrcBytes));
  if (crc_reader.get_u32() != crc32(stream.first(payload_bytes))) return DecodeError::kBadCrc;
  bytes::BigEndianReader r(stream.first(payload_bytes));
  if (marks) {
    auto& m = out.emplace<MarkObservations>();
    const DecodeError e = unpack_payload(r, m);
    if (e != DecodeError::kNone) return e;
    if (m.unit_id != canid::unit(can_id) || m.camera_id != canid::camera(can_id))
      return DecodeError::kOutOfRange;
  } else {
    auto& m = out.emplace<UnitHealth>();
    const DecodeError e = unpack_payload(r, m);
    if (e != DecodeError::kNone) return e;
    if (m.unit_id != canid::unit(can_id)) return DecodeError::kOutOfRange;
  }
  return DecodeError::kNone;
}

}  // namespace storetrack::msg
