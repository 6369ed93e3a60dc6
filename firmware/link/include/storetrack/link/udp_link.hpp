// UDP sender: one datagram per message (docs/icd.md "UDP framing"), unicast or multicast,
// non-blocking. A full socket buffer (EAGAIN/ENOBUFS) drops the datagram, counted.
#pragma once

#include <netinet/in.h>

#include <cstdint>
#include <string>

#include "storetrack/link/observation_link.hpp"

namespace storetrack::link {

struct UdpLinkConfig {
  std::string destination = "127.0.0.1:50000";  ///< IPv4 "address:port"; 224.0.0.0/4 = multicast
  std::string multicast_interface{};  ///< IPv4 address of the multicast interface ("": default)
  int multicast_ttl = 1;
  bool multicast_loop = true;  ///< deliver multicast to receivers on this host too
  int send_buffer_bytes = 0;   ///< SO_SNDBUF (0: kernel default)
  int dscp = 46;               ///< IP DSCP (46 = EF, expedited forwarding); -1: leave
};

/// Parses "a.b.c.d:port"; returns 0 or -EINVAL.
int parse_ipv4_endpoint(const std::string& text, sockaddr_in& out);

class UdpLink final : public ObservationLink {
 public:
  explicit UdpLink(UdpLinkConfig config);
  ~UdpLink() override;
  UdpLink(const UdpLink&) = delete;
  UdpLink& operator=(const UdpLink&) = delete;

  int open() override;
  void close() override;
  int send(const msg::MarkObservations& m) override;
  int send(const msg::UnitHealth& m) override;
  LinkStats stats() const override { return stats_.snapshot(); }
  const char* name() const override { return name_.c_str(); }
  const char* error() const override { return error_.c_str(); }

 private:
  int send_bytes(int length, bool is_observation);

  UdpLinkConfig config_;
  std::string name_;
  std::string error_;
  int fd_ = -1;
  sockaddr_in destination_{};
  std::uint32_t datagram_seq_ = 0;
  std::uint8_t buffer_[1472] = {};
  AtomicLinkStats stats_;
};

}  // namespace storetrack::link
