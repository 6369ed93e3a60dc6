#include "storetrack/ingest/receivers.hpp"

#include <arpa/inet.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <linux/filter.h>
#include <linux/sock_diag.h>
#include <net/if.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstring>
#include <optional>

#include "storetrack/msg/canfd_linux.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::ingest {

std::string describe(const RefusedVersion& refused) {
  if (!refused.seen) return "";
  const auto id = static_cast<msg::MessageId>(refused.message_id);
  const char* name = id == msg::MessageId::kMarkObservations ? "MarkObservations"
                     : id == msg::MessageId::kUnitHealth     ? "UnitHealth"
                                                             : "message";
  return std::string(name) + " version " + std::to_string(refused.version) + " from unit " +
         std::to_string(refused.unit_id) + " (this host reads version " +
         std::to_string(msg::canid::message_version(id)) + ")";
}
namespace {

constexpr std::size_t kMaxAllowedSources = 1024;

// One recvmsg() that also returns the kernel's count of datagrams/frames dropped on this socket
// because its buffer was full (SO_RXQ_OVFL: cumulative since enabled, sent with a datagram).
ssize_t receive_one(int fd, void* buf, std::size_t len, int flags, sockaddr_in* from,
                    std::uint64_t& kernel_drops) {
  iovec iov{buf, len};
  alignas(cmsghdr) std::array<char, CMSG_SPACE(sizeof(std::uint32_t))> control{};
  msghdr m{};
  m.msg_name = from;
  m.msg_namelen = from ? sizeof *from : 0;
  m.msg_iov = &iov;
  m.msg_iovlen = 1;
  m.msg_control = control.data();
  m.msg_controllen = control.size();
  const ssize_t n = ::recvmsg(fd, &m, flags);
  if (n < 0) return n;
  for (cmsghdr* c = CMSG_FIRSTHDR(&m); c; c = CMSG_NXTHDR(&m, c)) {
    if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SO_RXQ_OVFL) {
      std::uint32_t dropped = 0;
      std::memcpy(&dropped, CMSG_DATA(c), sizeof dropped);
      kernel_drops = dropped;
    }
  }
  return n;
}

void enable_drop_count(int fd) {
  const int one = 1;
  setsockopt(fd, SOL_SOCKET, SO_RXQ_OVFL, &one, sizeof one);
}

// The same cumulative drop count (sk_drops) read from the socket itself (SO_MEMINFO's
// SK_MEMINFO_DROPS): SO_RXQ_OVFL reports it only with the next datagram received, so drops at
// the end of a burst stayed uncounted until (or unless) another datagram came.
void read_drop_count(int fd, std::uint64_t& kernel_drops) {
  std::array<std::uint32_t, SK_MEMINFO_VARS> meminfo{};
  socklen_t len = sizeof meminfo;
  if (getsockopt(fd, SOL_SOCKET, SO_MEMINFO, meminfo.data(), &len) != 0) return;
  if (len >= (SK_MEMINFO_DROPS + 1) * sizeof(std::uint32_t))
    kernel_drops = std::max<std::uint64_t>(kernel_drops, meminfo[SK_MEMINFO_DROPS]);
}

// The receive buffer the kernel grants: SO_RCVBUF is capped at net.core.rmem_max without an
// error, so a host asking for 4 MiB may get 208 KiB and drop bursts. Where the process may
// (CAP_NET_ADMIN), SO_RCVBUFFORCE goes past the cap. Returns the usable bytes (the kernel
// reports twice the payload figure it accounts, see socket(7)).
int set_receive_buffer(int fd, int bytes) {
  setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &bytes, sizeof bytes);
  int granted = 0;
  socklen_t len = sizeof granted;
  getsockopt(fd, SOL_SOCKET, SO_RCVBUF, &granted, &len);
  if (granted / 2 < bytes &&
      setsockopt(fd, SOL_SOCKET, SO_RCVBUFFORCE, &bytes, sizeof bytes) == 0) {
    len = sizeof granted;
    getsockopt(fd, SOL_SOCKET, SO_RCVBUF, &granted, &len);
  }
  return granted / 2;
}

// Classic BPF on a UDP socket sees the datagram from its UDP header (8 bytes; the payload
// follows) and the IP header at SKF_NET_OFF; loads are big-endian (network order).
constexpr std::uint32_t kUdpHeaderBytes = 8;

sock_filter statement(std::uint16_t code, std::uint32_t k) {
  return sock_filter{code, 0, 0, k};
}
sock_filter jump_if_equal(std::uint32_t k, std::uint8_t skip_if_true, std::uint8_t skip_if_false) {
  return sock_filter{BPF_JMP | BPF_JEQ | BPF_K, skip_if_true, skip_if_false, k};
}

}  // namespace

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
  // A socket bound to a unicast address never sees datagrams sent to a group: with a group, the
  // socket binds the group address (only its datagrams arrive) and `bind_address` names the
  // interface to join on, unless `interface_address` does.
  in_addr group{};
  if (!multicast_group.empty()) {
    if (inet_pton(AF_INET, multicast_group.c_str(), &group) != 1) return -EINVAL;
    addr.sin_addr = group;
  }
  fd_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd_ < 0) return -errno;
  const int one = 1;
  setsockopt(fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  // A large buffer absorbs bursts (all cameras of one exposure arrive together).
  counters_.receive_buffer_requested_bytes = static_cast<std::uint64_t>(receive_buffer_bytes);
  counters_.receive_buffer_bytes =
      static_cast<std::uint64_t>(set_receive_buffer(fd_, receive_buffer_bytes));
  enable_drop_count(fd_);
  if (::bind(fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    const int e = errno;
    close();
    return -e;
  }
  if (!multicast_group.empty()) {
    ip_mreq mreq{};
    mreq.imr_multiaddr = group;
    const std::string ifa = !interface_address.empty() ? interface_address : bind_to;
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

int UdpReceiver::allow_source(int unit_id, const std::string& address) {
  in_addr a{};
  if (unit_id < 0 || unit_id > 254 || inet_pton(AF_INET, address.c_str(), &a) != 1) return -EINVAL;
  if (source_allowed(static_cast<std::uint8_t>(unit_id), a.s_addr)) return 0;
  if (allowed_.size() >= kMaxAllowedSources) return -ENOSPC;
  allowed_.push_back({static_cast<std::uint8_t>(unit_id), a.s_addr});
  return 0;
}

bool UdpReceiver::source_allowed(std::uint8_t unit_id, std::uint32_t address) const {
  return std::any_of(allowed_.begin(), allowed_.end(), [&](const AllowedSource& s) {
    return s.unit_id == unit_id && s.address == address;
  });
}

int UdpReceiver::install_kernel_filter() {
  if (fd_ < 0) return -EBADF;
  if (allowed_.empty()) return -EINVAL;
  if (allowed_.size() > kMaxKernelFilteredSources) return -E2BIG;
  constexpr std::uint32_t kAccept = 0xFFFFFFFF, kDrop = 0;
  std::vector<sock_filter> program = {
      statement(BPF_LD | BPF_H | BPF_ABS, kUdpHeaderBytes + 0),  // the datagram's magic
      jump_if_equal(msg::kUdpMagic, 1, 0),
      statement(BPF_RET | BPF_K, kDrop),
      statement(BPF_LD | BPF_B | BPF_ABS, kUdpHeaderBytes + 5),  // unit id
      statement(BPF_MISC | BPF_TAX, 0),
  };
  // One block per allowed source; every jump stays inside its block (jump offsets are 8 bits).
  for (const AllowedSource& s : allowed_) {
    program.push_back(statement(BPF_LD | BPF_W | BPF_ABS,
                                static_cast<std::uint32_t>(SKF_NET_OFF) + 12));  // IPv4 source
    program.push_back(jump_if_equal(ntohl(s.address), 0, 3));
    program.push_back(statement(BPF_MISC | BPF_TXA, 0));
    program.push_back(jump_if_equal(s.unit_id, 0, 1));
    program.push_back(statement(BPF_RET | BPF_K, kAccept));
  }
  program.push_back(statement(BPF_RET | BPF_K, kDrop));
  const sock_fprog fprog{static_cast<unsigned short>(program.size()), program.data()};
  if (setsockopt(fd_, SOL_SOCKET, SO_ATTACH_FILTER, &fprog, sizeof fprog) != 0) return -errno;
  counters_.kernel_filter_sources = allowed_.size();
  return 0;
}

int UdpReceiver::receive(const MessageHandler& handler, int max_datagrams) {
  if (fd_ < 0) return -EBADF;
  std::array<std::uint8_t, 2048> buf{};
  int decoded = 0;
  msg::AnyMessage message;
  int read = 0;
  for (; read < max_datagrams; ++read) {
    sockaddr_in from{};
    const ssize_t n =
        receive_one(fd_, buf.data(), buf.size(), MSG_TRUNC, &from, counters_.kernel_drops);
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN || errno == EWOULDBLOCK) break;
      ++counters_.receive_errors;
      return -errno;
    }
    ++counters_.datagrams;
    counters_.bytes += static_cast<std::uint64_t>(n);
    const bool truncated = static_cast<std::size_t>(n) > buf.size();
    const std::span<const std::uint8_t> received(buf.data(),
                                                 std::min(buf.size(), static_cast<std::size_t>(n)));
    // The raw record of this datagram, whatever the verdict (recorded before the handler runs).
    auto record_raw = [&](std::uint8_t verdict, bool accepted) {
      if (!raw_) return;
      msg::RawObservation r{};
      r.source_kind = static_cast<std::uint8_t>(RawSourceKind::kUdp);
      r.arrival_tai_ns = time::tai_now_ns();
      r.source_address = ntohl(from.sin_addr.s_addr);
      r.source_port = ntohs(from.sin_port);
      r.unit_id = received.size() > 5 ? received[5] : 0xFF;  // as the header claims it
      r.camera_id = 0xFF;
      if (accepted)
        if (const auto* m = std::get_if<msg::MarkObservations>(&message))
          r.camera_id = m->camera_id;
      r.flags = static_cast<std::uint8_t>((accepted ? msg::raw_observation_flags::kAccepted : 0) |
                                          (truncated ? msg::raw_observation_flags::kTruncated : 0));
      r.decode_error = verdict;
      r.received_bytes = static_cast<std::uint32_t>(n);
      r.message_bytes = static_cast<std::uint16_t>(received.size());
      raw_(r, received);
    };
    if (truncated) {  // larger than any storetrack datagram
      counters_.decode_errors.record(msg::DecodeError::kBadLength);
      record_raw(static_cast<std::uint8_t>(msg::DecodeError::kBadLength), false);
      continue;
    }
    msg::DatagramHeader header;
    const msg::DecodeError e = msg::decode_datagram(received, message, &header);
    counters_.decode_errors.record(e);
    if (e != msg::DecodeError::kNone) {
      if (e == msg::DecodeError::kBadVersion)
        counters_.last_refused_version = {true, header.message_id, header.message_version,
                                          header.unit_id};
      record_raw(static_cast<std::uint8_t>(e), false);
      continue;
    }
    const std::uint8_t u = header.unit_id;
    if (!allowed_.empty() && !source_allowed(u, from.sin_addr.s_addr)) {
      ++counters_.spoofed_source;  // before the gap count: a forger cannot disturb it
      record_raw(kRawSpoofedSource, false);
      continue;
    }
    record_raw(0, true);
    // Per-unit datagram counter: forward gaps are datagrams lost on the way.
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
  if (read >= max_datagrams) ++counters_.budget_exhausted;
  read_drop_count(fd_, counters_.kernel_drops);
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
  interface_index_ = index;
  fd_ = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (fd_ < 0) return -errno;
  const int enable = 1;
  if (setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &enable, sizeof enable) != 0) {
    const int e = errno;
    close();
    return -e;
  }
  enable_drop_count(fd_);
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

int CanFdReceiver::receive(const MessageHandler& handler, int max_frames) {
  if (fd_ < 0) return -EBADF;
  int decoded = 0;
  canfd_frame raw{};
  std::optional<msg::AnyMessage> completed;
  int read = 0;
  for (; read < max_frames; ++read) {
    const ssize_t n = receive_one(fd_, &raw, sizeof raw, 0, nullptr, counters_.kernel_drops);
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
    if (e == msg::DecodeError::kBadVersion)
      counters_.last_refused_version = {true, msg::canid::fid(frame.can_id),
                                        msg::canid::version(frame.can_id),
                                        msg::canid::unit(frame.can_id)};
    if (raw_) {
      if (const auto t = reassembler_.finished_transfer()) {
        const std::size_t kept = std::min(t->stream.size(), msg::kRawObservationMaxTailBytes);
        msg::RawObservation r{};
        r.source_kind = static_cast<std::uint8_t>(RawSourceKind::kCanFd);
        r.arrival_tai_ns = time::tai_now_ns();
        r.source_address = t->can_id;
        r.source_port = static_cast<std::uint16_t>(interface_index_);
        r.unit_id = msg::canid::unit(t->can_id);
        r.camera_id = msg::canid::camera(t->can_id);
        const bool accepted = completed.has_value();
        r.flags = static_cast<std::uint8_t>(
            (accepted ? msg::raw_observation_flags::kAccepted : 0) |
            (kept < t->stream.size() ? msg::raw_observation_flags::kTruncated : 0));
        r.decode_error = static_cast<std::uint8_t>(e);
        r.received_bytes = static_cast<std::uint32_t>(t->stream.size());
        r.message_bytes = static_cast<std::uint16_t>(kept);
        raw_(r, t->stream.first(kept));
      }
    }
    if (completed) {
      ++counters_.decoded;
      ++decoded;
      handler(*completed);
    }
  }
  if (read >= max_frames) ++counters_.budget_exhausted;
  read_drop_count(fd_, counters_.kernel_drops);
  return decoded;
}

void CanFdReceiver::close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

}  // namespace storetrack::ingest
