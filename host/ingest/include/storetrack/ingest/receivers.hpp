// Socket adapters of the host's input: UDP (unicast or multicast) and CAN FD (SocketCAN raw,
// CAN_RAW_FD_FRAMES). Both are non-blocking: the caller poll()s fd() and then calls receive(),
// which reads at most a fixed number of datagrams/frames (so a flood cannot starve alignment
// and processing: the rest waits in the socket for the next call), decodes them and hands
// complete messages to a callback. Datagrams the kernel dropped because the socket buffer was
// full are counted (SO_RXQ_OVFL, SO_MEMINFO). Decoding lives in common/msg; these classes only move
// bytes, filter senders and count.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "storetrack/msg/canfd_codec.hpp"
#include "storetrack/msg/decode_error.hpp"
#include "storetrack/msg/udp_codec.hpp"

namespace storetrack::ingest {

using MessageHandler = std::function<void(const msg::AnyMessage&)>;
/// Every observation message as received, valid or not (raw recording, docs/fti-output.md):
/// the record (arrival time, source, the receiver's verdict) and the bytes, a view valid only
/// during the call. Called before the MessageHandler of the same message.
using RawObservationHandler =
    std::function<void(const msg::RawObservation&, std::span<const std::uint8_t>)>;
/// RawObservation.source_kind: a message (UDP, CAN FD) or one of the aligner's clock events the
/// host records beside them, so that a replay gives the aligner every input at its time.
enum class RawSourceKind : std::uint8_t {
  kUdp = 0,
  kCanFd = 1,
  kAlignerDeadline = 2,  ///< ExposureAligner::poll released or took back exposures
  kAlignerFlush = 3,     ///< ExposureAligner::flush at the host's end
};
/// The RawObservation.decode_error of a valid datagram from a sender that is not allowed.
inline constexpr std::uint8_t kRawSpoofedSource = 0xFE;

/// Most datagrams one UdpReceiver::receive() call reads: 256 is 80 ms of the nominal 8 cameras
/// x 400 fps and 8 ms of a 10x flood, so one loop turn never holds alignment longer than that.
inline constexpr int kMaxDatagramsPerReceive = 256;
/// Most (unit id, source address) combinations the kernel filter carries: 5 classic-BPF
/// instructions each within the kernel's 4096 (BPF_MAXINSNS).
inline constexpr std::size_t kMaxKernelFilteredSources = 800;
/// Most frames one CanFdReceiver::receive() call reads (a MarkObservations is up to 9 frames).
inline constexpr int kMaxCanFramesPerReceive = 1024;

/// The last message refused for its version (an older or newer unit's layout), so that the
/// stats can name it: message id, the version it carried, the sending unit.
struct RefusedVersion {
  bool seen = false;
  std::uint8_t message_id = 0;
  std::uint8_t version = 0;
  std::uint8_t unit_id = 0;
};

/// "MarkObservations version 1 from unit 3 (this host reads version 2)"; "" if none was refused.
std::string describe(const RefusedVersion& refused);

struct UdpReceiverCounters {
  std::uint64_t datagrams = 0;
  std::uint64_t bytes = 0;
  std::uint64_t decoded = 0;
  std::uint64_t receive_errors = 0;
  msg::DecodeCounters decode_errors;    ///< index = DecodeError
  RefusedVersion last_refused_version;  ///< of the kBadVersion ones
  std::uint64_t datagram_seq_gaps = 0;  ///< datagrams missing per the senders' counters
  std::uint64_t spoofed_source = 0;     ///< valid datagram, (unit id, source address) not allowed
  std::uint64_t kernel_drops = 0;       ///< dropped by the kernel: socket buffer full
  std::uint64_t budget_exhausted = 0;   ///< receive() calls that stopped at the per-call bound
  std::uint64_t receive_buffer_requested_bytes = 0;  ///< socket receive buffer asked for
  std::uint64_t receive_buffer_bytes = 0;            ///< granted (capped by net.core.rmem_max)
  /// Allowed sources in the kernel filter (0: no filter; then every datagram reaches the host).
  std::uint64_t kernel_filter_sources = 0;
};

class UdpReceiver {
 public:
  UdpReceiver() = default;
  ~UdpReceiver();
  UdpReceiver(const UdpReceiver&) = delete;
  UdpReceiver& operator=(const UdpReceiver&) = delete;

  /// Binds `bind_address:port` (0.0.0.0 for all). With `multicast_group`, binds the group's
  /// address instead and joins it on the interface with address `interface_address` (default:
  /// `bind_address`). The receive buffer granted is in counters(). Returns 0 or -errno.
  int open(const std::string& bind_address, std::uint16_t port,
           const std::string& multicast_group = "", const std::string& interface_address = "",
           int receive_buffer_bytes = 4 << 20);
  int fd() const { return fd_; }
  /// Accepts datagrams of unit `unit_id` (0..254) from IPv4 `address` (a.b.c.d). Once any source
  /// is allowed, every other (unit id, source address) combination is counted as spoofed and
  /// dropped. Returns 0 or -EINVAL.
  int allow_source(int unit_id, const std::string& address);
  /// Moves the source check into the kernel: a classic BPF socket filter (SO_ATTACH_FILTER)
  /// lets only datagrams with the storetrack magic from an allowed (unit id, IPv4 source)
  /// into the socket buffer, so a flood of garbage or foreign-unit traffic is dropped before it
  /// takes buffer space (and the host's time) from valid datagrams. The kernel counts what it
  /// refuses with its buffer-full drops (`kernel_drops`); valid datagrams lost are then the
  /// senders' counter gaps (`datagram_seq_gaps`), and `spoofed_source` / decode errors count
  /// only what passed the filter (a forger copying an allowed unit id and address: the CRC and
  /// the aligner still check it). Call after allow_source(). Returns 0, -EINVAL with no allowed
  /// source, -E2BIG past kMaxKernelFilteredSources, or -errno of setsockopt.
  int install_kernel_filter();
  /// Reads until the socket is empty or `max_datagrams` were read; returns messages decoded or
  /// -errno.
  int receive(const MessageHandler& handler, int max_datagrams = kMaxDatagramsPerReceive);
  /// Hands every datagram read (its bytes as received, up to the receive buffer) to `raw`
  /// too; an empty function turns it off.
  void set_raw_handler(RawObservationHandler raw) { raw_ = std::move(raw); }
  void close();
  const UdpReceiverCounters& counters() const { return counters_; }
  /// The bound port (useful with port 0).
  std::uint16_t port() const;

 private:
  struct AllowedSource {
    std::uint8_t unit_id;
    std::uint32_t address;  // network byte order
  };
  bool source_allowed(std::uint8_t unit_id, std::uint32_t address) const;

  int fd_ = -1;
  UdpReceiverCounters counters_;
  RawObservationHandler raw_;
  std::vector<AllowedSource> allowed_;  // one per configured (unit, address); empty: any
  std::uint32_t last_seq_[256] = {};
  bool seen_unit_[256] = {};
};

struct CanReceiverCounters {
  std::uint64_t frames = 0;
  std::uint64_t classic_or_bad_frames = 0;  ///< not an extended-id CAN FD data frame
  std::uint64_t decoded = 0;
  std::uint64_t receive_errors = 0;
  msg::DecodeCounters decode_errors;
  RefusedVersion last_refused_version;  ///< of the kBadVersion ones (the identifier's fields)
  std::uint64_t kernel_drops = 0;       ///< dropped by the kernel: socket buffer full
  std::uint64_t budget_exhausted = 0;   ///< receive() calls that stopped at the per-call bound
};

class CanFdReceiver {
 public:
  CanFdReceiver() = default;
  ~CanFdReceiver();
  CanFdReceiver(const CanFdReceiver&) = delete;
  CanFdReceiver& operator=(const CanFdReceiver&) = delete;

  /// Opens a raw CAN socket on `interface_name` (e.g. vcan0, can0) with CAN FD frames enabled.
  /// Returns 0 or -errno (-ENODEV when the interface does not exist).
  int open(const std::string& interface_name);
  int fd() const { return fd_; }
  /// Reads until the socket is empty or `max_frames` were read; returns messages completed or
  /// -errno.
  int receive(const MessageHandler& handler, int max_frames = kMaxCanFramesPerReceive);
  /// Hands every reassembled transfer (all fragments in, valid or not) to `raw` too.
  void set_raw_handler(RawObservationHandler raw) { raw_ = std::move(raw); }
  /// Expires stale partial transfers (call when idle).
  void expire(std::int64_t now_ns) { reassembler_.expire(now_ns); }
  void close();
  const CanReceiverCounters& counters() const { return counters_; }
  const msg::CanReassemblyCounters& reassembly_counters() const { return reassembler_.counters(); }

 private:
  int fd_ = -1;
  unsigned interface_index_ = 0;
  RawObservationHandler raw_;
  msg::CanFdReassembler reassembler_;
  CanReceiverCounters counters_;
};

}  // namespace storetrack::ingest
