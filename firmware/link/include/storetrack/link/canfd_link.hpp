// CAN FD sender over SocketCAN (CAN_RAW + CAN_RAW_FD_FRAMES), docs/icd.md "CAN FD framing".
//
// The socket is non-blocking and receives only error frames (CAN_RAW_ERR_FILTER; data frames
// are filtered out). Transmit back-pressure drops WHOLE exposures: before writing a transfer
// the socket's queued bytes (SIOCOUTQ) are compared with its send buffer, and a transfer that
// does not fit is not started; if the queue fills mid-transfer anyway the rest is abandoned
// (counted as partial: the host's reassembler expires it). While the controller is bus-off
// (error frame CAN_ERR_BUSOFF, until CAN_ERR_RESTARTED or a successful probe write once a
// second) exposures are dropped without touching the bus. Nothing here ever blocks.
#pragma once

#include <cstdint>
#include <string>

#include "storetrack/link/observation_link.hpp"
#include "storetrack/msg/canfd_codec.hpp"

namespace storetrack::link {

struct CanFdLinkConfig {
  std::string interface = "can0";
  int send_buffer_bytes = 0;  ///< SO_SNDBUF (0: kernel default)
  /// Socket-buffer bytes charged per queued frame (skb truesize), for the whole-transfer room
  /// check; conservative for x86-64 and arm64 kernels.
  int bytes_per_queued_frame = 1024;
  std::int64_t bus_off_probe_interval_ns = 1'000'000'000;
};

/// What one error frame means (pure; linux/can/error.h classes).
struct CanErrorEvent {
  bool bus_off = false;
  bool restarted = false;
  bool tx_timeout = false;
  bool controller_problem = false;  ///< warning / passive levels
  bool protocol_violation = false;
  bool no_ack = false;
  bool bus_error = false;
};
CanErrorEvent classify_error_frame(std::uint32_t can_id, const std::uint8_t* data, int len);

class CanFdLink final : public ObservationLink {
 public:
  explicit CanFdLink(CanFdLinkConfig config);
  ~CanFdLink() override;
  CanFdLink(const CanFdLink&) = delete;
  CanFdLink& operator=(const CanFdLink&) = delete;

  int open() override;
  void close() override;
  int send(const msg::MarkObservations& m) override;
  int send(const msg::UnitHealth& m) override;
  void service() override;
  LinkStats stats() const override { return stats_.snapshot(); }
  const char* name() const override { return name_.c_str(); }
  const char* error() const override { return error_.c_str(); }

 private:
  int send_frames(int count, bool is_observation);
  bool room_for(int frames);

  CanFdLinkConfig config_;
  std::string name_;
  std::string error_;
  int fd_ = -1;
  int sndbuf_ = 0;
  std::int64_t last_probe_ns_ = 0;
  msg::CanFdFrame frames_[msg::kCanFdMaxFragments] = {};
  AtomicLinkStats stats_;
};

}  // namespace storetrack::link
