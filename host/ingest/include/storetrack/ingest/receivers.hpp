// Socket adapters of the host's input: UDP (unicast or multicast) and CAN FD (SocketCAN raw,
// CAN_RAW_FD_FRAMES). Both are non-blocking: the caller poll()s fd() and then drains with
// receive(), which decodes every datagram/frame and hands complete messages to a callback.
// Decoding lives in common/msg; these classes only move bytes and count.
#pragma once

#include <cstdint>
#include <functional>
#include <string>

#include "storetrack/msg/canfd_codec.hpp"
#include "storetrack/msg/decode_error.hpp"
#include "storetrack/msg/udp_codec.hpp"

namespace storetrack::ingest {

using MessageHandler = std::function<void(const msg::AnyMessage&)>;

struct UdpReceiverCounters {
  std::uint64_t datagrams = 0;
  std::uint64_t bytes = 0;
  std::uint64_t decoded = 0;
  std::uint64_t receive_errors = 0;
  msg::DecodeCounters decode_errors;    ///< index = DecodeError
  std::uint64_t datagram_seq_gaps = 0;  ///< datagrams missing per the senders' counters
};

class UdpReceiver {
 public:
  UdpReceiver() = default;
  ~UdpReceiver();
  UdpReceiver(const UdpReceiver&) = delete;
  UdpReceiver& operator=(const UdpReceiver&) = delete;

  /// Binds `bind_address:port` (0.0.0.0 for all); joins `multicast_group` on the interface
  /// with address `interface_address` when the group is given. Returns 0 or -errno.
  int open(const std::string& bind_address, std::uint16_t port,
           const std::string& multicast_group = "", const std::string& interface_address = "",
           int receive_buffer_bytes = 4 << 20);
  int fd() const { return fd_; }
  /// Reads until the socket is empty; returns messages decoded or -errno.
  int receive(const MessageHandler& handler);
  void close();
  const UdpReceiverCounters& counters() const { return counters_; }
  /// The bound port (useful with port 0).
  std::uint16_t port() const;

 private:
  int fd_ = -1;
  UdpReceiverCounters counters_;
  std::uint32_t last_seq_[256] = {};
  bool seen_unit_[256] = {};
};

struct CanReceiverCounters {
  std::uint64_t frames = 0;
  std::uint64_t classic_or_bad_frames = 0;  ///< not an extended-id CAN FD data frame
  std::uint64_t decoded = 0;
  std::uint64_t receive_errors = 0;
  msg::DecodeCounters decode_errors;
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
  int receive(const MessageHandler& handler);
  /// Expires stale partial transfers (call when idle).
  void expire(std::int64_t now_ns) { reassembler_.expire(now_ns); }
  void close();
  const CanReceiverCounters& counters() const { return counters_; }
  const msg::CanReassemblyCounters& reassembly_counters() const { return reassembler_.counters(); }

 private:
  int fd_ = -1;
  msg::CanFdReassembler reassembler_;
  CanReceiverCounters counters_;
};

}  // namespace storetrack::ingest
