// Stand-ins for the live page's browsers in storetrack-host-latency-bench (docs/live-view.md,
// issue 32's isolation measurement): readers that GET /events and read the stream continuously,
// as EventSource does, and stalled clients that send the request and never read a byte (a
// browser that hangs). They run on one thread of the bench, polling every socket, so twenty
// readers cost the bench one thread rather than twenty.
//
// A stalled connection is replaced by a new one every few seconds: the server drops it once
// its socket buffers are full and a write made no progress for 1 s, and the client cannot see
// that drop (the server's FIN waits behind the data it never reads), so without replacement
// the stall would last only the first seconds of a run.
#pragma once

#include <atomic>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

namespace storetrack::hostapp {

struct LiveEndpoint {
  std::string host;  ///< numeric IPv4 address, as storetrack-host prints it
  int port = 0;
};

/// "http://127.0.0.1:8080/" -> {"127.0.0.1", 8080}; nullopt for anything else.
std::optional<LiveEndpoint> parse_live_url(std::string_view url);

/// What the clients saw; the bench prints it so a run whose readers got nothing is visible.
struct LiveClientCounts {
  int readers = 0;
  int readers_streaming = 0;       ///< answered "HTTP/1.1 200" with the event stream
  int readers_refused = 0;         ///< connection failed or another status (503: too many clients)
  int readers_closed_early = 0;    ///< the server closed a reader's stream before stop()
  std::uint64_t events_total = 0;  ///< "event: snapshot" records over all readers
  std::uint64_t events_min = 0;    ///< the reader that received the fewest
  std::uint64_t events_max = 0;
  int stalled = 0;
  int stalled_connections = 0;  ///< opened by the stalled clients (first ones and replacements)
  /// The most bytes a stalled connection held unread when it was closed: a full receive buffer
  /// shows the server's writes to it stalled (else the stall was never felt by the server).
  std::size_t stalled_unread_bytes_max = 0;
};

/// The clients, connected at construction; stop() (or the destructor) closes them.
class LiveClients {
 public:
  LiveClients(LiveEndpoint endpoint, int readers, int stalled);
  ~LiveClients();
  LiveClients(const LiveClients&) = delete;
  LiveClients& operator=(const LiveClients&) = delete;

  /// True once every reader has its response header (streaming or refused), false on timeout.
  bool wait_for_responses(double timeout_s) const;
  LiveClientCounts stop();

 private:
  struct Reader;
  struct Stalled;
  void poll_loop();
  void read_from(Reader& r);
  void replace_if_held_long_enough(Stalled& s);
  void close_stalled(Stalled& s);

  LiveEndpoint endpoint_;
  std::vector<Reader> readers_;
  std::vector<Stalled> stalled_;
  std::atomic<int> responses_{0};
  std::atomic<bool> stop_{false};
  std::thread thread_;
  bool stopped_ = false;
};

}  // namespace storetrack::hostapp
