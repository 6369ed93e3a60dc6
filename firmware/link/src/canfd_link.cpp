#include "storetrack/link/canfd_link.hpp"

#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <linux/sockios.h>
#include <net/if.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "storetrack/msg/canfd_linux.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::link {

CanErrorEvent classify_error_frame(std::uint32_t can_id, const std::uint8_t* data, int len) {
  CanErrorEvent e;
  if ((can_id & CAN_ERR_FLAG) == 0) return e;
  const std::uint32_t cls = can_id & CAN_ERR_MASK;
  e.bus_off = (cls & CAN_ERR_BUSOFF) != 0;
  e.restarted = (cls & CAN_ERR_RESTARTED) != 0;
  e.tx_timeout = (cls & CAN_ERR_TX_TIMEOUT) != 0;
  e.controller_problem = (cls & CAN_ERR_CRTL) != 0;
  e.protocol_violation = (cls & CAN_ERR_PROT) != 0;
  e.no_ack = (cls & CAN_ERR_ACK) != 0;
  e.bus_error = (cls & CAN_ERR_BUSERROR) != 0;
  // A controller-state report of "back to error-active" also ends a bus-off episode.
  if (e.controller_problem && len > 1 && data != nullptr && data[1] == CAN_ERR_CRTL_ACTIVE) {
    e.restarted = true;
  }
  return e;
}

CanFdLink::CanFdLink(CanFdLinkConfig config) : config_(std::move(config)) {
  name_ = "canfd " + config_.interface;
}

CanFdLink::~CanFdLink() {
  close();
}

int CanFdLink::open() {
  if (fd_ >= 0) return 0;
  if (config_.interface.empty() || config_.interface.size() >= IFNAMSIZ) {
    error_ = name_ + ": bad interface name";
    return -EINVAL;
  }
  fd_ = socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (fd_ < 0) {
    const int err = errno;
    error_ = name_ + ": socket(PF_CAN, CAN_RAW): " + std::strerror(err) +
             (err == EAFNOSUPPORT ? " (kernel without CAN support: modprobe can_raw)" : "");
    fd_ = -1;
    return -err;
  }
  auto fail = [&](const std::string& what) {
    const int err = errno;
    error_ = name_ + ": " + what + ": " + std::strerror(err);
    close();
    return -err;
  };
  const int on = 1;
  if (setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on) < 0) {
    return fail("CAN_RAW_FD_FRAMES (interface without CAN FD?)");
  }
  // Receive no data frames, only error frames.
  if (setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_FILTER, nullptr, 0) < 0) return fail("CAN_RAW_FILTER");
  const can_err_mask_t err_mask = CAN_ERR_TX_TIMEOUT | CAN_ERR_CRTL | CAN_ERR_PROT | CAN_ERR_ACK |
                                  CAN_ERR_BUSOFF | CAN_ERR_BUSERROR | CAN_ERR_RESTARTED;
  if (setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &err_mask, sizeof err_mask) < 0) {
    return fail("CAN_RAW_ERR_FILTER");
  }
  if (config_.send_buffer_bytes > 0 &&
      setsockopt(fd_, SOL_SOCKET, SO_SNDBUF, &config_.send_buffer_bytes, sizeof(int)) < 0) {
    return fail("SO_SNDBUF");
  }
  socklen_t len = sizeof sndbuf_;
  if (getsockopt(fd_, SOL_SOCKET, SO_SNDBUF, &sndbuf_, &len) < 0) sndbuf_ = 0;
  const unsigned ifindex = if_nametoindex(config_.interface.c_str());
  if (ifindex == 0) return fail("no such interface");
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(ifindex);
  if (bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0) return fail("bind");
  // The interface must carry CAN FD frames (mtu 72).
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, config_.interface.c_str(), IFNAMSIZ - 1);
  if (ioctl(fd_, SIOCGIFMTU, &ifr) == 0 && ifr.ifr_mtu != CANFD_MTU) {
    errno = EPROTONOSUPPORT;
    return fail("interface mtu is " + std::to_string(ifr.ifr_mtu) +
                ", not 72 (CAN FD): ip link set " + config_.interface + " mtu 72 / fd on");
  }
  return 0;
}

void CanFdLink::close() {
  if (fd_ >= 0) {
    ::close(fd_);
    fd_ = -1;
  }
}

void CanFdLink::service() {
  if (fd_ < 0) return;
  for (int i = 0; i < 64; ++i) {  // bounded: never starve the capture loop
    canfd_frame f{};
    const ssize_t n = recv(fd_, &f, sizeof f, MSG_DONTWAIT);
    if (n < 0) break;
    if (n != CAN_MTU && n != CANFD_MTU) continue;
    if ((f.can_id & CAN_ERR_FLAG) == 0) continue;
    AtomicLinkStats::bump(stats_.error_frames);
    const CanErrorEvent e = classify_error_frame(f.can_id, f.data, f.len);
    if (e.bus_off && !stats_.bus_off.load(std::memory_order_relaxed)) {
      stats_.bus_off.store(true, std::memory_order_relaxed);
      AtomicLinkStats::bump(stats_.bus_off_events);
      last_probe_ns_ = time::monotonic_now_ns();
    }
    if (e.restarted) stats_.bus_off.store(false, std::memory_order_relaxed);
  }
}

bool CanFdLink::room_for(int frames) {
  if (sndbuf_ <= 0) return true;
  int queued = 0;
  if (ioctl(fd_, SIOCOUTQ, &queued) < 0) return true;  // not supported: rely on write errors
  return queued + frames * config_.bytes_per_queued_frame <= sndbuf_;
}

int CanFdLink::send_frames(int count, bool is_observation) {
  if (fd_ < 0) return -ENOTCONN;
  service();
  if (stats_.bus_off.load(std::memory_order_relaxed)) {
    // Probe once per interval: a controller restarted by restart-ms may not report it.
    const std::int64_t now = time::monotonic_now_ns();
    if (now - last_probe_ns_ < config_.bus_off_probe_interval_ns) {
      if (is_observation) AtomicLinkStats::bump(stats_.dropped_exposures);
      return -EAGAIN;
    }
    last_probe_ns_ = now;
  }
  if (!room_for(count)) {
    if (is_observation) AtomicLinkStats::bump(stats_.dropped_exposures);
    return -EAGAIN;
  }
  for (int i = 0; i < count; ++i) {
    const canfd_frame lf = msg::to_linux(frames_[i]);
    const ssize_t n = write(fd_, &lf, CANFD_MTU);
    if (n == CANFD_MTU) continue;
    const int err = n < 0 ? errno : EIO;
    stats_.last_errno.store(err, std::memory_order_relaxed);
    const bool pressure = err == EAGAIN || err == EWOULDBLOCK || err == ENOBUFS;
    if (err == ENETDOWN || err == ENXIO || err == ENODEV) {
      stats_.link_down.store(true, std::memory_order_relaxed);
    }
    if (i > 0) AtomicLinkStats::bump(stats_.partial_exposures);
    if (pressure) {
      if (is_observation) AtomicLinkStats::bump(stats_.dropped_exposures);
      return -EAGAIN;
    }
    AtomicLinkStats::bump(stats_.tx_errors);
    if (is_observation) AtomicLinkStats::bump(stats_.dropped_exposures);
    return -err;
  }
  stats_.link_down.store(false, std::memory_order_relaxed);
  stats_.bus_off.store(false, std::memory_order_relaxed);  // a probe got through
  AtomicLinkStats::bump(is_observation ? stats_.observations_sent : stats_.health_sent);
  return 0;
}

int CanFdLink::send(const msg::MarkObservations& m) {
  const int n = msg::encode_canfd(m, std::span<msg::CanFdFrame>(frames_));
  if (n < 0) {
    AtomicLinkStats::bump(stats_.encode_errors);
    return n;
  }
  return send_frames(n, true);
}

int CanFdLink::send(const msg::UnitHealth& m) {
  const int n = msg::encode_canfd(m, std::span<msg::CanFdFrame>(frames_));
  if (n < 0) {
    AtomicLinkStats::bump(stats_.encode_errors);
    return n;
  }
  return send_frames(n, false);
}

}  // namespace storetrack::link
