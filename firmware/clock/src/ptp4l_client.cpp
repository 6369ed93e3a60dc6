#include "storetrack/clock/ptp4l_client.hpp"

#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <ctime>
#include <utility>

namespace storetrack::clock {
namespace {

/// The one wrapper every system call of the client goes through: -errno on failure (EINTR
/// retried), the call's non-negative result otherwise.
template <typename Call>
long checked(Call&& call) {
  for (;;) {
    const long rc = static_cast<long>(call());
    if (rc >= 0) return rc;
    if (errno != EINTR) return -errno;
  }
}

bool make_address(const std::string& path, sockaddr_un& out, socklen_t& length) {
  out = {};
  out.sun_family = AF_UNIX;
  if (path.empty() || path.size() >= sizeof(out.sun_path)) return false;
  std::memcpy(out.sun_path, path.data(), path.size());
  length = static_cast<socklen_t>(offsetof(sockaddr_un, sun_path) + path.size() + 1);
  return true;
}

std::int64_t monotonic_ms() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000 + ts.tv_nsec / 1'000'000;
}

std::atomic<unsigned> g_instance{0};  // several clients in one process get distinct paths

constexpr std::size_t kMaxSocketPath = sizeof(sockaddr_un{}.sun_path) - 1;  // 107 on Linux
constexpr const char* kClientPrefix = "/storetrack-pmc.";

std::string client_path_for(const std::string& dir, long pid, unsigned instance) {
  return dir + kClientPrefix + std::to_string(pid) + "." + std::to_string(instance);
}

}  // namespace

std::string socket_path_problem(const Ptp4lClientConfig& config) {
  if (config.uds_path.empty()) return "ptp4l.uds_path is empty";
  if (config.uds_path.size() > kMaxSocketPath)
    return "ptp4l.uds_path is " + std::to_string(config.uds_path.size()) +
           " bytes, longer than a UNIX socket path may be (" + std::to_string(kMaxSocketPath) +
           "): " + config.uds_path;
  if (config.client_dir.empty()) return "ptp4l.client_dir is empty";
  // The longest name this client can bind: a pid up to Linux's PID_MAX_LIMIT (2^22, 7 digits)
  // and an instance number up to 2^32 - 1.
  const std::size_t longest = client_path_for(config.client_dir, 4194304, 4294967295U).size();
  if (longest > kMaxSocketPath)
    return "ptp4l.client_dir is too long by " + std::to_string(longest - kMaxSocketPath) +
           " bytes: the client's socket " + config.client_dir + kClientPrefix +
           "<pid>.<n> may take " + std::to_string(longest) + " of the " +
           std::to_string(kMaxSocketPath) + " bytes a UNIX socket path may have";
  return {};
}

Ptp4lClient::Ptp4lClient(Ptp4lClientConfig config) : config_(std::move(config)) {}

Ptp4lClient::~Ptp4lClient() {
  close();
}

int Ptp4lClient::open() {
  close();
  // The same rule as at start-up, whatever this process's pid: a path that fits only for a
  // small pid must not work on the bench and fail on the aircraft.
  if (std::string problem = socket_path_problem(config_); !problem.empty()) {
    error_ = std::move(problem);
    return -ENAMETOOLONG;
  }
  client_path_ = client_path_for(config_.client_dir, ::getpid(), g_instance.fetch_add(1));
  sockaddr_un self{};
  socklen_t self_length = 0;
  sockaddr_un peer{};
  socklen_t peer_length = 0;
  if (!make_address(client_path_, self, self_length) ||
      !make_address(config_.uds_path, peer, peer_length)) {
    error_ = "socket path too long or empty: " + client_path_ + " / " + config_.uds_path;
    return -ENAMETOOLONG;
  }
  const long fd = checked([] { return ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0); });
  if (fd < 0) {
    error_ = std::string("socket(AF_UNIX): ") + std::strerror(static_cast<int>(-fd));
    return static_cast<int>(fd);
  }
  fd_ = static_cast<int>(fd);
  checked([&] { return ::unlink(client_path_.c_str()); });  // a stale file of an earlier run
  const long rc =
      checked([&] { return ::bind(fd_, reinterpret_cast<const sockaddr*>(&self), self_length); });
  if (rc < 0) {
    error_ = "bind " + client_path_ + ": " + std::strerror(static_cast<int>(-rc));
    ::close(fd_);
    fd_ = -1;
    return static_cast<int>(rc);
  }
  // Datagram sockets may be "connected" to fix the peer: sendto()/recv() then see only ptp4l.
  // Not done: connect() fails while ptp4l is not running yet, and the unit may start first.
  return 0;
}

void Ptp4lClient::close() {
  if (fd_ < 0) return;
  // Not through checked(): close() must not be retried on EINTR (Linux frees the descriptor
  // anyway; a retry could close one another thread just opened).
  ::close(fd_);
  fd_ = -1;
  checked([&] { return ::unlink(client_path_.c_str()); });
}

int Ptp4lClient::get(ManagementId id, ManagementReply& reply) {
  if (fd_ < 0) return -EBADF;
  RequestHeader header;
  header.domain_number = config_.domain_number;
  header.source.port_number = static_cast<std::uint16_t>(::getpid());
  header.sequence_id = ++sequence_id_;
  const int length = encode_get_request(header, id, tx_);
  if (length < 0) return length;
  sockaddr_un peer{};
  socklen_t peer_length = 0;
  make_address(config_.uds_path, peer, peer_length);
  stats_.requests.fetch_add(1, std::memory_order_relaxed);
  const long sent = checked([&] {
    return ::sendto(fd_, tx_, static_cast<std::size_t>(length), MSG_DONTWAIT,
                    reinterpret_cast<const sockaddr*>(&peer), peer_length);
  });
  if (sent < 0) {
    stats_.send_errors.fetch_add(1, std::memory_order_relaxed);
    stats_.last_errno.store(static_cast<int>(-sent), std::memory_order_relaxed);
    return static_cast<int>(sent);
  }
  return await_reply(id, header.sequence_id, reply);
}

int Ptp4lClient::await_reply(ManagementId id, std::uint16_t sequence_id, ManagementReply& reply) {
  const std::int64_t deadline_ms = monotonic_ms() + config_.reply_timeout_ms;
  for (;;) {
    const std::int64_t remaining_ms = deadline_ms - monotonic_ms();
    if (remaining_ms <= 0) break;
    pollfd p{fd_, POLLIN, 0};
    const long ready = checked([&] { return ::poll(&p, 1, static_cast<int>(remaining_ms)); });
    if (ready < 0) {
      stats_.last_errno.store(static_cast<int>(-ready), std::memory_order_relaxed);
      break;
    }
    if (ready == 0) break;
    const long n = checked([&] { return ::recv(fd_, rx_, sizeof rx_, MSG_DONTWAIT); });
    if (n < 0) {
      if (n == -EAGAIN) continue;
      stats_.last_errno.store(static_cast<int>(-n), std::memory_order_relaxed);
      break;
    }
    const ReplyStatus status = decode_reply(
        std::span<const std::uint8_t>(rx_, static_cast<std::size_t>(n)), sequence_id, id, reply);
    switch (status) {
      case ReplyStatus::kOk:
        stats_.replies.fetch_add(1, std::memory_order_relaxed);
        return 0;
      case ReplyStatus::kErrorStatus:
        stats_.error_status.fetch_add(1, std::memory_order_relaxed);
        return -EPROTO;
      case ReplyStatus::kWrongSequence:
        stats_.stale.fetch_add(1, std::memory_order_relaxed);
        break;  // an answer to an earlier, timed-out request: keep waiting for ours
      default:
        stats_.malformed.fetch_add(1, std::memory_order_relaxed);
        break;
    }
  }
  stats_.timeouts.fetch_add(1, std::memory_order_relaxed);
  return -ETIMEDOUT;
}

Ptp4lClientStats Ptp4lClient::stats() const {
  Ptp4lClientStats s;
  s.requests = stats_.requests.load(std::memory_order_relaxed);
  s.replies = stats_.replies.load(std::memory_order_relaxed);
  s.timeouts = stats_.timeouts.load(std::memory_order_relaxed);
  s.send_errors = stats_.send_errors.load(std::memory_order_relaxed);
  s.malformed = stats_.malformed.load(std::memory_order_relaxed);
  s.stale = stats_.stale.load(std::memory_order_relaxed);
  s.error_status = stats_.error_status.load(std::memory_order_relaxed);
  s.last_errno = stats_.last_errno.load(std::memory_order_relaxed);
  return s;
}

}  // namespace storetrack::clock
