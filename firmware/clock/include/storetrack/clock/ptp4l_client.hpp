// ptp4l's management interface over its UNIX domain socket, as `pmc -u` uses it: an AF_UNIX
// datagram socket bound to a path of its own (ptp4l sends the reply to the sender's address, so
// it must be a path: abstract names do not cross network namespaces), GET requests sent to
// ptp4l's `uds_address`, replies awaited with poll() up to a timeout. Every system call goes
// through one wrapper that returns -errno. No allocation after open(); nothing throws.
#pragma once

#include <atomic>
#include <cstdint>
#include <span>
#include <string>

#include "storetrack/clock/ptp_management.hpp"

namespace storetrack::clock {

struct Ptp4lClientConfig {
  std::string uds_path = "/var/run/ptp4l";  ///< ptp4l's uds_address
  /// Where this client binds its own socket (pmc uses /var/run/pmc.<pid>); the file is
  /// <client_dir>/storetrack-pmc.<pid>.<n>, removed at close().
  std::string client_dir = "/run/storetrack";
  int reply_timeout_ms = 100;      ///< per request; ptp4l answers from its main loop within ~1 ms
  std::uint8_t domain_number = 0;  ///< ptp4l's domainNumber (pmc -d)
};

/// Counters since open(); written by the polling thread, read by anyone.
struct Ptp4lClientStats {
  std::uint64_t requests = 0;
  std::uint64_t replies = 0;       ///< valid replies to the request in flight
  std::uint64_t timeouts = 0;      ///< no valid reply within reply_timeout_ms
  std::uint64_t send_errors = 0;   ///< sendto failed (ptp4l not running: ENOENT/ECONNREFUSED)
  std::uint64_t malformed = 0;     ///< datagrams that failed decode_reply (not the two below)
  std::uint64_t stale = 0;         ///< replies with an older sequenceId (a late answer)
  std::uint64_t error_status = 0;  ///< MANAGEMENT_ERROR_STATUS replies
  int last_errno = 0;
};

/// Empty when both socket paths fit a sockaddr_un (107 bytes and the NUL), whatever the pid
/// and instance number the client's own path gets; else which configured path is too long and
/// by how much. The unit checks it at start-up, so a deep directory is named before the first
/// poll instead of failing every open().
std::string socket_path_problem(const Ptp4lClientConfig& config);

class Ptp4lClient {
 public:
  explicit Ptp4lClient(Ptp4lClientConfig config);
  ~Ptp4lClient();
  Ptp4lClient(const Ptp4lClient&) = delete;
  Ptp4lClient& operator=(const Ptp4lClient&) = delete;

  /// Creates and binds the client socket: 0 or -errno (error() says where).
  int open();
  void close();
  /// Sends GET `id` and waits for its reply. 0: `reply` is valid (its data views this client's
  /// buffer until the next get()); -ETIMEDOUT: no reply; -EPROTO: ptp4l answered with
  /// MANAGEMENT_ERROR_STATUS (reply.error_id); other -errno: the send failed.
  int get(ManagementId id, ManagementReply& reply);

  Ptp4lClientStats stats() const;
  const std::string& error() const { return error_; }
  const std::string& client_path() const { return client_path_; }

 private:
  int await_reply(ManagementId id, std::uint16_t sequence_id, ManagementReply& reply);

  Ptp4lClientConfig config_;
  std::string client_path_;
  std::string error_;
  int fd_ = -1;
  std::uint16_t sequence_id_ = 0;
  std::uint8_t tx_[kGetRequestBytes] = {};
  std::uint8_t rx_[kMaxReplyBytes] = {};
  struct AtomicStats {
    std::atomic<std::uint64_t> requests{0}, replies{0}, timeouts{0}, send_errors{0}, malformed{0},
        stale{0}, error_status{0};
    std::atomic<int> last_errno{0};
  } stats_;
};

}  // namespace storetrack::clock
