#include "storetrack/link/udp_link.hpp"

#include <arpa/inet.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "storetrack/msg/udp_codec.hpp"

namespace storetrack::link {

static_assert(msg::kMaxDatagramBytes <= 1472, "UdpLink buffer holds one datagram");

int parse_ipv4_endpoint(const std::string& text, sockaddr_in& out) {
  const auto colon = text.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 >= text.size()) return -EINVAL;
  const std::string host = text.substr(0, colon);
  const std::string port_text = text.substr(colon + 1);
  long port = 0;
  for (char c : port_text) {
    if (c < '0' || c > '9') return -EINVAL;
    port = port * 10 + (c - '0');
    if (port > 65535) return -EINVAL;
  }
  if (port == 0) return -EINVAL;
  out = sockaddr_in{};
  out.sin_family = AF_INET;
  out.sin_port = htons(static_cast<std::uint16_t>(port));
  if (inet_pton(AF_INET, host.c_str(), &out.sin_addr) != 1) return -EINVAL;
  return 0;
}

UdpLink::UdpLink(UdpLinkConfig config) : config_(std::move(config)) {
  name_ = "udp " + config_.destination;
}

UdpLink::~UdpLink() {
  close();
}

int UdpLink::open() {
  if (fd_ >= 0) return 0;
  if (parse_ipv4_endpoint(config_.destination, destination_) < 0) {
    error_ = name_ + ": destination must be IPv4 address:port";
    return -EINVAL;
  }
  fd_ = socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd_ < 0) {
    const int err = errno;
    error_ = name_ + ": socket: " + std::strerror(err);
    return -err;
  }
  auto fail = [&](const char* what) {
    const int err = errno;
    error_ = name_ + ": " + what + ": " + std::strerror(err);
    close();
    return -err;
  };
  if (config_.send_buffer_bytes > 0 &&
      setsockopt(fd_, SOL_SOCKET, SO_SNDBUF, &config_.send_buffer_bytes, sizeof(int)) < 0) {
    return fail("SO_SNDBUF");
  }
  if (config_.dscp >= 0) {
    const int tos = (config_.dscp & 0x3F) << 2;
    setsockopt(fd_, IPPROTO_IP, IP_TOS, &tos, sizeof tos);  // best effort: QoS marking only
  }
  const std::uint32_t addr = ntohl(destination_.sin_addr.s_addr);
  if ((addr >> 28) == 0xE) {  // 224.0.0.0/4: multicast
    const int ttl = config_.multicast_ttl;
    if (setsockopt(fd_, IPPROTO_IP, IP_MULTICAST_TTL, &ttl, sizeof ttl) < 0) {
      return fail("IP_MULTICAST_TTL");
    }
    const int loop = config_.multicast_loop ? 1 : 0;
    if (setsockopt(fd_, IPPROTO_IP, IP_MULTICAST_LOOP, &loop, sizeof loop) < 0) {
      return fail("IP_MULTICAST_LOOP");
    }
    if (!config_.multicast_interface.empty()) {
      in_addr iface{};
      if (inet_pton(AF_INET, config_.multicast_interface.c_str(), &iface) != 1) {
        error_ = name_ + ": multicast interface must be an IPv4 address";
        close();
        return -EINVAL;
      }
      if (setsockopt(fd_, IPPROTO_IP, IP_MULTICAST_IF, &iface, sizeof iface) < 0) {
        return fail("IP_MULTICAST_IF");
      }
    }
  }
  return 0;
}

void UdpLink::close() {
  if (fd_ >= 0) {
    ::close(fd_);
    fd_ = -1;
  }
}

int UdpLink::send_bytes(int length, bool is_observation) {
  const ssize_t n = sendto(fd_, buffer_, static_cast<std::size_t>(length), MSG_DONTWAIT,
                           reinterpret_cast<const sockaddr*>(&destination_), sizeof destination_);
  if (n == length) {
    ++datagram_seq_;
    stats_.link_down.store(false, std::memory_order_relaxed);
    AtomicLinkStats::bump(is_observation ? stats_.observations_sent : stats_.health_sent);
    return 0;
  }
  const int err = n < 0 ? errno : EMSGSIZE;
  stats_.last_errno.store(err, std::memory_order_relaxed);
  if (err == EAGAIN || err == EWOULDBLOCK || err == ENOBUFS) {
    if (is_observation) AtomicLinkStats::bump(stats_.dropped_exposures);
    return -EAGAIN;
  }
  if (err == ENETUNREACH || err == ENETDOWN || err == EHOSTUNREACH) {
    stats_.link_down.store(true, std::memory_order_relaxed);
  }
  AtomicLinkStats::bump(stats_.tx_errors);
  return -err;
}

int UdpLink::send(const msg::MarkObservations& m) {
  if (fd_ < 0) return -ENOTCONN;
  const int len = msg::encode_datagram(m, std::span<std::uint8_t>(buffer_), datagram_seq_);
  if (len < 0) {
    AtomicLinkStats::bump(stats_.encode_errors);
    return len;
  }
  return send_bytes(len, true);
}

int UdpLink::send(const msg::UnitHealth& m) {
  if (fd_ < 0) return -ENOTCONN;
  const int len = msg::encode_datagram(m, std::span<std::uint8_t>(buffer_), datagram_seq_);
  if (len < 0) {
    AtomicLinkStats::bump(stats_.encode_errors);
    return len;
  }
  return send_bytes(len, false);
}

}  // namespace storetrack::link
