#include "live_bench_clients.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <limits>

namespace storetrack::hostapp {
namespace {

constexpr std::string_view kEventsRequest =
    "GET /events HTTP/1.1\r\nHost: storetrack\r\nAccept: text/event-stream\r\n\r\n";
// The server's framing of one snapshot (host/live live_server.cpp): one per event received.
constexpr std::string_view kEventMarker = "event: snapshot\n";
// How long a stalled connection is kept: the server's buffers fill in ~1.5 s of events at
// 20 Hz and it drops the stream after 1 s without progress; then a new one stalls again.
constexpr auto kStallHold = std::chrono::seconds(3);

// A blocking connect to the loopback server, then the request; -1 when either fails.
int open_events_stream(const LiveEndpoint& e) {
  const int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return -1;
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(e.port));
  inet_pton(AF_INET, e.host.c_str(), &a.sin_addr);
  if (connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
      send(fd, kEventsRequest.data(), kEventsRequest.size(), MSG_NOSIGNAL) !=
          static_cast<ssize_t>(kEventsRequest.size())) {
    close(fd);
    return -1;
  }
  return fd;
}

// Occurrences of a marker in a stream read in pieces: the marker may straddle two reads (and
// the chunked encoding's own framing lies between chunks, never inside an event's text).
class MarkerCounter {
 public:
  explicit MarkerCounter(std::string_view marker) : marker_(marker) {}
  void feed(std::string_view bytes) {
    tail_.append(bytes);
    for (std::size_t at = tail_.find(marker_); at != std::string::npos;
         at = tail_.find(marker_, at + marker_.size()))
      ++count_;
    const std::size_t keep = std::min(tail_.size(), marker_.size() - 1);
    tail_.erase(0, tail_.size() - keep);
  }
  std::uint64_t count() const { return count_; }

 private:
  std::string_view marker_;
  std::string tail_;
  std::uint64_t count_ = 0;
};

}  // namespace

struct LiveClients::Reader {
  int fd = -1;
  bool have_header = false;
  bool streaming = false;  // the header said 200
  bool closed = false;     // by the server, or refused
  std::string header;
  MarkerCounter events{kEventMarker};
};

struct LiveClients::Stalled {
  int fd = -1;
  std::chrono::steady_clock::time_point opened;
  int connections = 0;
  std::size_t unread_bytes_max = 0;
};

std::optional<LiveEndpoint> parse_live_url(std::string_view url) {
  constexpr std::string_view kScheme = "http://";
  if (url.substr(0, kScheme.size()) != kScheme) return std::nullopt;
  url.remove_prefix(kScheme.size());
  const std::size_t colon = url.find(':');
  if (colon == std::string_view::npos) return std::nullopt;
  LiveEndpoint e{std::string(url.substr(0, colon)), 0};
  for (std::size_t i = colon + 1; i < url.size() && url[i] != '/'; ++i) {
    if (url[i] < '0' || url[i] > '9' || e.port > 65535) return std::nullopt;
    e.port = e.port * 10 + (url[i] - '0');
  }
  if (e.port <= 0 || e.port > 65535) return std::nullopt;
  return e;
}

LiveClients::LiveClients(LiveEndpoint endpoint, int readers, int stalled)
    : endpoint_(std::move(endpoint)),
      readers_(static_cast<std::size_t>(readers)),
      stalled_(static_cast<std::size_t>(stalled)) {
  for (Reader& r : readers_) {
    r.fd = open_events_stream(endpoint_);
    if (r.fd < 0) {
      r.have_header = r.closed = true;  // refused: counts as answered, never streams
      ++responses_;
    }
  }
  for (Stalled& s : stalled_)
    replace_if_held_long_enough(s);
  thread_ = std::thread([this] { poll_loop(); });
}

LiveClients::~LiveClients() {
  stop();
}

bool LiveClients::wait_for_responses(double timeout_s) const {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (responses_.load() < static_cast<int>(readers_.size())) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return true;
}

void LiveClients::read_from(Reader& r) {
  std::array<char, 65536> buf;
  const ssize_t n = recv(r.fd, buf.data(), buf.size(), MSG_DONTWAIT);
  if (n <= 0) {
    if (n < 0 && (errno == EAGAIN || errno == EINTR)) return;
    r.closed = true;
    if (!r.have_header) {  // closed before any answer: refused, and answered for the wait
      r.have_header = true;
      ++responses_;
    }
    return;
  }
  std::string_view bytes(buf.data(), static_cast<std::size_t>(n));
  if (!r.have_header) {
    r.header.append(bytes);
    const std::size_t end = r.header.find("\r\n\r\n");
    if (end == std::string::npos) return;
    r.have_header = true;
    r.streaming = r.header.rfind("HTTP/1.1 200", 0) == 0;
    bytes = std::string_view(r.header).substr(end + 4);
    ++responses_;
  }
  r.events.feed(bytes);
}

void LiveClients::close_stalled(Stalled& s) {
  if (s.fd < 0) return;
  int unread = 0;
  if (ioctl(s.fd, FIONREAD, &unread) == 0)
    s.unread_bytes_max = std::max(s.unread_bytes_max, static_cast<std::size_t>(unread));
  close(s.fd);
  s.fd = -1;
}

// A new stalled connection when there is none (or its connect failed) or the current one is
// kStallHold old.
void LiveClients::replace_if_held_long_enough(Stalled& s) {
  const auto now = std::chrono::steady_clock::now();
  if (s.fd >= 0 && now - s.opened < kStallHold) return;
  close_stalled(s);
  s.fd = open_events_stream(endpoint_);
  s.opened = now;
  s.connections += s.fd >= 0 ? 1 : 0;
}

void LiveClients::poll_loop() {
  std::vector<pollfd> fds;
  while (!stop_.load()) {
    fds.clear();
    for (const Reader& r : readers_)
      fds.push_back({r.closed ? -1 : r.fd, POLLIN, 0});  // negative fd: poll skips it
    // Without readers, poll() on no descriptor is the 50 ms wait between stalled checks.
    if (poll(fds.data(), fds.size(), 50) < 0 && errno != EINTR) return;
    for (std::size_t i = 0; i < readers_.size(); ++i)
      if (fds[i].revents != 0) read_from(readers_[i]);
    for (Stalled& s : stalled_)
      replace_if_held_long_enough(s);
  }
}

LiveClientCounts LiveClients::stop() {
  LiveClientCounts c;
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  c.readers = static_cast<int>(readers_.size());
  c.stalled = static_cast<int>(stalled_.size());
  c.events_min = readers_.empty() ? 0 : std::numeric_limits<std::uint64_t>::max();
  for (const Reader& r : readers_) {
    c.readers_streaming += r.streaming ? 1 : 0;
    c.readers_refused += r.streaming ? 0 : 1;
    c.readers_closed_early += r.streaming && r.closed ? 1 : 0;
    c.events_total += r.events.count();
    c.events_min = std::min(c.events_min, r.events.count());
    c.events_max = std::max(c.events_max, r.events.count());
  }
  if (!stopped_) {
    for (Reader& r : readers_)
      if (r.fd >= 0) close(r.fd);
    for (Stalled& s : stalled_)
      close_stalled(s);
    stopped_ = true;
  }
  for (const Stalled& s : stalled_) {
    c.stalled_connections += s.connections;
    c.stalled_unread_bytes_max = std::max(c.stalled_unread_bytes_max, s.unread_bytes_max);
  }
  return c;
}

}  // namespace storetrack::hostapp
