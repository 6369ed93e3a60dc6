#include "storetrack/ingest/receivers.hpp"

#include <arpa/inet.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>
#include <optional>

#include "storetrack/msg/canfd_linux.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::ingest {

UdpReceiver::~UdpReceiver() {
  close();
}

int UdpReceiver::open(const std::string& bind_address, std::uint16_t port,
                      const std::string& multicast_group, const std::string& interface_address,
                      int receive_buffer_bytes) {
  close();
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(port);
  const std::string bind_to = bind_address.empty() ? "0.0.0.0" : bind_address;
  if (inet_pton(AF_INET, bind_to.c_str(), &addr.sin_addr) != 1) return -EINVAL;
  fd_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd_ < 0) return -errno;
  const int one = 1;
  setsockopt(fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  // A large buffer absorbs bursts (all cameras of one exposure arrive together).
  setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &receive_buffer_bytes, sizeof receive_buffer_bytes);
  if (::bind(fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    const int e = errno;
    close();
    return -e;
  }
  if (!multicast_group.empty()) {
    ip_mreq mreq{};
    if (inet_pton(AF_INET, multicast_group.c_str(), &mreq.imr_multiaddr) != 1) {
      close();
      return -EINVAL;
    }
    const std::string ifa = interface_address.empty() ? "0.0.0.0" : interface_address;
    if (inet_pton(AF_INET, ifa.c_str(), &mreq.imr_interface) != 1) {
      close();
      return -EINVAL;
    }
    if (setsockopt(fd_, IPPROTO_IP, IP_ADD_MEMBERSHIP, &mreq, sizeof mreq) != 0) {
      const int e = errno;
      close();
      return -e;
    }
  }
  return 0;
}

std::uint16_t UdpReceiver::port() const {
  sockaddr_in addr{};
  socklen_t len = sizeof addr;
  if (fd_ < 0 || getsockname(fd_, reinterpret_cast<sockaddr*>(&addr), &len) != 0) return 0;
  return ntohs(addr.sin_port);
}

int UdpReceiver::receive(const MessageHandler& handler) {
  if (fd_ < 0) return -EBADF;
  std::array<std::uint8_t, 2048> buf{};
  int decoded = 0;
  msg::AnyMessage message;
  for (;;) {
    const ssize_t n = ::recv(fd_, buf.data(), buf.size(), MSG_TRUNC);
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN || errno == EWOULDBLOCK) break;
      ++counters_.receive_errors;
      return -errno;
    }
    ++counters_.datagrams;
    counters_.bytes += static_cast<std::uint64_t>(n);
    if (static_cast<std::size_t>(n) > buf.size()) {  // larger than any storetrack datagram
      counters_.decode_errors.record(msg::DecodeError::kBadLength);
      continue;
    }
    msg::DatagramHeader header;
    const msg::DecodeError e = msg::decode_datagram(
        std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(n)), message, &header);
    counters_.decode_errors.record(e);
    if (e != msg::DecodeError::kNone) continue;
    // Per-unit datagram counter: forward gaps are datagrams lost on the way.
    const std::uint8_t u = header.unit_id;
    if (seen_unit_[u]) {
      const auto gap = static_cast<std::int32_t>(header.datagram_seq - last_seq_[u] - 1);
      if (gap > 0 && gap < (1 << 20))
        counters_.datagram_seq_gaps += static_cast<std::uint64_t>(gap);
      if (gap >= 0) last_seq_[u] = header.datagram_seq;
    } else {
      seen_unit_[u] = true;
      last_seq_[u] = header.datagram_seq;
    }
    ++counters_.decoded;
    ++decoded;
    handler(message);
  }
  return decoded;
}

void UdpReceiver::close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

CanFdReceiver::~CanFdReceiver() {
  close();
}

int CanFdReceiver::open(const std::string& interface_name) {
  close();
  const unsigned index = if_nametoindex(interface_name.c_str());
  if (index == 0) return -ENODEV;
  fd_ = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (fd_ < 0) return -errno;
  const int enable = 1;
  if (setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &enable, sizeof enable) != 0) {
    const int e = errno;
    close();
    return -e;
  }
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(index);
  if (::bind(fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    const int e = errno;
    close();
    return -e;
  }
  return 0;
}

int CanFdReceiver::receive(const MessageHandler& handler) {
  if (fd_ < 0) return -EBADF;
  int decoded = 0;
  canfd_frame raw{};
  std::optional<msg::AnyMessage> completed;
  for (;;) {
    const ssize_t n = ::read(fd_, &raw, sizeof raw);
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN || errno == EWOULDBLOCK) break;
      ++counters_.receive_errors;
      return -errno;
    }
    ++counters_.frames;
    msg::CanFdFrame frame;
    // A classic CAN frame (CAN_MTU) carries no storetrack transfer.
    if (static_cast<std::size_t>(n) != CANFD_MTU || !msg::from_linux(raw, frame)) {
      ++counters_.classic_or_bad_frames;
      continue;
    }
    const msg::DecodeError e = reassembler_.push(frame, time::monotonic_now_ns(), completed);
    counters_.decode_errors.record(e);
    if (completed) {
      ++counters_.decoded;
      ++decoded;
      handler(*completed);
    }
  }
  return decoded;
}

void CanFdReceiver::close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

}  // namespace storetrack::ingest
