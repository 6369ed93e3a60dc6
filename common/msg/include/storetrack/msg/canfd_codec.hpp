// CAN FD framing (docs/icd.md "CAN FD framing"): one message = one transfer of 1..16 frames
// of up to 64 bytes. Transfer stream = payload (schema, big-endian) | CRC-32 over the payload.
// Each frame is self-contained:
//   29-bit identifier (ARINC 825 style, logical channel in the top bits)
//     bits 28..26  LCC        logical communication channel, 2 = NOC (normal operation)
//     bits 25..19  FID        message id from the schema (0x01 MarkObservations, 0x02 UnitHealth)
//     bits 18..11  unit_id
//     bits 10..3   camera_id  (0 for UnitHealth)
//     bits  2..0   version    the message's schema version (MarkObservations 2, UnitHealth 1):
//                             a layout this decoder does not read is refused by its first frame
//   data bytes 0..1  transfer sequence (trigger_seq low 16 bits; UnitHealth: report time/2^20 ns)
//   data byte  2     fragment index (bits 7..4) | fragment count - 1 (bits 3..0)
//   data bytes 3..   up to 61 bytes of the transfer stream; the last frame is padded with 0x00
//                    up to the next valid CAN FD length (DLC).
// Lower identifiers win arbitration: observations before health, low unit ids first.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>

#include "storetrack/msg/decode_error.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/msg/udp_codec.hpp"  // AnyMessage

namespace storetrack::msg {

/// A CAN FD frame as plain data; see canfd_linux.hpp for struct canfd_frame conversion.
struct CanFdFrame {
  std::uint32_t can_id = 0;  ///< 29-bit extended identifier, WITHOUT CAN_EFF_FLAG
  std::uint8_t len = 0;      ///< data length: 0..8, 12, 16, 20, 24, 32, 48 or 64
  std::uint8_t data[64] = {};
};

namespace canid {
inline constexpr unsigned kLccShift = 26, kLccBits = 3;
inline constexpr unsigned kFidShift = 19, kFidBits = 7;
inline constexpr unsigned kUnitShift = 11, kUnitBits = 8;
inline constexpr unsigned kCameraShift = 3, kCameraBits = 8;
inline constexpr unsigned kVersionShift = 0, kVersionBits = 3;
static_assert(kLccBits + kFidBits + kUnitBits + kCameraBits + kVersionBits == 29);
static_assert(kLccShift + kLccBits == 29 && kFidShift + kFidBits == kLccShift &&
              kUnitShift + kUnitBits == kFidShift && kCameraShift + kCameraBits == kUnitShift &&
              kVersionShift + kVersionBits == kCameraShift);
inline constexpr std::uint8_t kLccNoc = 2;  ///< ARINC 825 Normal Operation Channel
inline constexpr std::uint32_t kMask29 = 0x1FFFFFFF;

/// The version field of a message's CAN ID: its schema version (0 for an unknown message).
constexpr std::uint8_t message_version(MessageId id) {
  switch (id) {
    case MessageId::kMarkObservations:
      return kMarkObservationsVersion;
    case MessageId::kUnitHealth:
      return kUnitHealthVersion;
    default:
      return 0;
  }
}
static_assert(kMarkObservationsVersion < 8 && kUnitHealthVersion < 8, "3 version bits");

constexpr std::uint32_t make(std::uint8_t lcc, std::uint8_t fid, std::uint8_t unit,
                             std::uint8_t camera, std::uint8_t version) {
  return (std::uint32_t{lcc} & 0x7u) << kLccShift | (std::uint32_t{fid} & 0x7Fu) << kFidShift |
         std::uint32_t{unit} << kUnitShift | std::uint32_t{camera} << kCameraShift |
         (std::uint32_t{version} & 0x7u) << kVersionShift;
}
constexpr std::uint8_t lcc(std::uint32_t id) {
  return (id >> kLccShift) & 0x7u;
}
constexpr std::uint8_t fid(std::uint32_t id) {
  return (id >> kFidShift) & 0x7Fu;
}
constexpr std::uint8_t unit(std::uint32_t id) {
  return (id >> kUnitShift) & 0xFFu;
}
constexpr std::uint8_t camera(std::uint32_t id) {
  return (id >> kCameraShift) & 0xFFu;
}
constexpr std::uint8_t version(std::uint32_t id) {
  return (id >> kVersionShift) & 0x7u;
}
}  // namespace canid

inline constexpr std::size_t kCanFdMaxData = 64;
inline constexpr std::size_t kCanFdFragmentHeaderBytes = 3;
inline constexpr std::size_t kCanFdFragmentPayloadBytes = kCanFdMaxData - kCanFdFragmentHeaderBytes;
inline constexpr std::size_t kCanFdTransferCrcBytes = 4;
inline constexpr std::size_t kCanFdMaxFragments = 16;  ///< 4-bit fragment index/count
inline constexpr std::size_t kCanFdMaxTransferBytes = kMaxPayloadBytes + kCanFdTransferCrcBytes;
inline constexpr std::size_t kCanFdMaxFramesPerMessage =
    (kMarkObservationsMaxPayloadBytes + kCanFdTransferCrcBytes + kCanFdFragmentPayloadBytes - 1) /
    kCanFdFragmentPayloadBytes;
static_assert(kCanFdMaxFramesPerMessage <= kCanFdMaxFragments, "fragment index field too small");
static_assert(kCanFdMaxFramesPerMessage == 10, "wire layout size");

/// Smallest valid CAN FD data length >= n (n <= 64).
std::uint8_t canfd_round_up_len(std::size_t n);
/// Frames a message needs.
std::size_t canfd_frame_count(const MarkObservations& m);
std::size_t canfd_frame_count(const UnitHealth& m);

/// Encodes one message into frames. Returns the number of frames written, -ENOSPC when `out`
/// has too few frames, -ERANGE when a value cannot be carried (see encode_datagram).
int encode_canfd(const MarkObservations& m, std::span<CanFdFrame> out);
int encode_canfd(const UnitHealth& m, std::span<CanFdFrame> out);

struct CanReassemblyCounters {
  std::uint64_t frames = 0;              ///< frames pushed
  std::uint64_t fragments_accepted = 0;  ///< new fragments stored
  std::uint64_t completed = 0;           ///< messages delivered
  std::uint64_t duplicates = 0;          ///< fragment already held, or of a delivered transfer
  std::uint64_t not_ours = 0;            ///< wrong channel (LCC) or shape: kBadMagic
  std::uint64_t bad_version = 0;         ///< kBadVersion
  std::uint64_t bad_length = 0;          ///< kTooShort / kBadLength (frame or transfer layout)
  std::uint64_t crc_errors = 0;          ///< kBadCrc: transfer CRC-32 mismatch
  std::uint64_t unknown_type = 0;        ///< kUnknownType
  std::uint64_t out_of_range = 0;        ///< kOutOfRange: bad values or id/payload mismatch
  std::uint64_t timeouts = 0;            ///< incomplete transfers expired
  std::uint64_t evictions = 0;           ///< incomplete transfers dropped for lack of slots
  std::uint64_t fragments_lost = 0;      ///< missing fragments of expired/evicted transfers
};

/// The message of one reassembled transfer stream (payload and CRC-32, as
/// CanFdReassembler::FinishedTransfer holds it) sent under `can_id`: its length, CRC and content,
/// and that it names the unit and camera the identifier names. Not the fragment shape or the
/// transfer sequence (the frames' headers, not in the stream): a recorded transfer the host
/// accepted is replayed through it (storetrack-post).
DecodeError decode_canfd_stream(std::uint32_t can_id, std::span<const std::uint8_t> stream,
                                AnyMessage& out);

struct CanReassemblerConfig {
  std::int64_t timeout_ns = 20'000'000;  ///< incomplete transfer lifetime (8 exposures at 400 fps)
};

/// Host-side reassembly of CAN FD transfers. Fixed capacity (no allocation after
/// construction), tolerant of loss, duplicates and reordering across interleaved transfers of
/// many units/cameras. Not thread-safe: one per receiving thread.
class CanFdReassembler {
 public:
  static constexpr std::size_t kSlots = 32;  ///< transfers in flight
  /// Finished transfers remembered for one timeout, so that late duplicates are recognised.
  static constexpr std::size_t kRecentKeys = 64;

  explicit CanFdReassembler(const CanReassemblerConfig& config = {});

  /// Feeds one frame received at `now_ns` (any monotonic clock). When it completes a transfer,
  /// `completed` holds the message (else it is reset). Returns kNone for frames that were
  /// accepted, duplicates or completed transfers, else the error of this frame/transfer.
  /// Also expires incomplete transfers older than the timeout.
  DecodeError push(const CanFdFrame& frame, std::int64_t now_ns,
                   std::optional<AnyMessage>& completed);
  /// As above, time from CLOCK_MONOTONIC.
  DecodeError push(const CanFdFrame& frame, std::optional<AnyMessage>& completed);
  /// Expires incomplete transfers older than the timeout (call when the bus is idle).
  void expire(std::int64_t now_ns);

  const CanReassemblyCounters& counters() const { return counters_; }
  std::size_t in_flight() const;

  /// A transfer whose fragments were all in, as reassembled (payload, CRC-32 and the last
  /// frame's padding), before any check of its content.
  struct FinishedTransfer {
    std::uint32_t can_id = 0;  ///< the frames' identifier
    std::span<const std::uint8_t> stream;
  };
  /// The transfer the last push() finished, valid or not (the push's result says which), or
  /// nullopt. The view stays valid until the next push (raw recording of every message).
  std::optional<FinishedTransfer> finished_transfer() const {
    if (!finished_) return std::nullopt;
    return finished_transfer_;
  }

 private:
  struct Key {
    std::uint32_t can_id = 0;  ///< identifies message/unit/camera
    std::uint16_t seq = 0;
    bool operator==(const Key&) const = default;
  };
  struct RecentKey {
    Key key;
    std::int64_t done_ns = 0;
  };
  struct Slot {
    bool used = false;
    Key key;
    std::uint8_t count = 0;
    std::uint16_t received_mask = 0;
    std::uint8_t last_len = 0;  ///< stream bytes in the last fragment (frame len - header)
    std::int64_t first_ns = 0;
    std::array<std::uint8_t, kCanFdMaxFragments * kCanFdFragmentPayloadBytes> stream{};
  };

  DecodeError count_error(DecodeError e);
  DecodeError finish(Slot& slot, std::int64_t now_ns, std::optional<AnyMessage>& completed);
  void release(Slot& slot, bool lost);

  CanReassemblerConfig config_;
  CanReassemblyCounters counters_;
  std::array<Slot, kSlots> slots_{};
  std::array<RecentKey, kRecentKeys> recent_{};
  std::size_t recent_next_ = 0;
  std::size_t recent_size_ = 0;
  bool finished_ = false;
  FinishedTransfer finished_transfer_;
};

}  // namespace storetrack::msg
