#include "storetrack/live/live_server.hpp"

#include <arpa/inet.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <httplib.h>
#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <stdexcept>
#include <thread>

#include "live_assets.hpp"

namespace storetrack::live {

LiveAddress parse_live_address(const std::string& text) {
  const std::string expected =
      "expected ADDR:PORT, e.g. 127.0.0.1:8080 (there is no default address: name the interface "
      "the page is served on; 0.0.0.0 serves every interface)";
  const auto colon = text.rfind(':');
  if (text.empty() || colon == std::string::npos || colon == 0 || colon + 1 == text.size())
    throw std::invalid_argument("--live '" + text + "': " + expected);
  LiveAddress a;
  a.host = text.substr(0, colon);
  const std::string port = text.substr(colon + 1);
  if (port.size() > 5 ||
      !std::all_of(port.begin(), port.end(), [](char ch) { return ch >= '0' && ch <= '9'; }))
    throw std::invalid_argument("--live '" + text + "': port '" + port + "' is not a number; " +
                                expected);
  a.port = std::stoi(port);
  if (a.port > 65535)
    throw std::invalid_argument("--live '" + text + "': port " + port + " is above 65535; " +
                                expected);
  in_addr ip{};
  if (a.host != "localhost" && inet_pton(AF_INET, a.host.c_str(), &ip) != 1)
    throw std::invalid_argument("--live '" + text + "': '" + a.host +
                                "' is not an IPv4 address (a.b.c.d) or localhost; " + expected);
  return a;
}

namespace {

// The server's threads yield to the real-time loop (a nice value is per thread on Linux, and
// threads a thread creates inherit it: httplib's workers are made by the listening thread).
void lower_this_thread(int nice) {
  if (nice > 0) (void)setpriority(PRIO_PROCESS, static_cast<id_t>(gettid()), nice);
}

}  // namespace

struct LiveServer::Impl {
  Impl(const LiveServerConfig& c, LiveScene s, LivePublisher& p)
      : config(c), scene(std::move(s)), publisher(p) {}

  LiveServerConfig config;
  LiveScene scene;
  LivePublisher& publisher;  // read (take/front) by the broadcaster thread only
  httplib::Server http;
  std::thread listener, broadcaster;
  int bound_port = 0;
  bool started = false;

  std::mutex mutex;  // guards the three below; never taken by the real-time thread
  std::condition_variable changed;
  std::shared_ptr<const std::string> event, latest_json;
  std::uint64_t event_seq = 0;
  std::atomic<bool> stopping{false};

  std::atomic<std::uint64_t> requests{0}, not_found{0}, refused{0}, dropped{0}, events_sent{0},
      snapshots_read{0};
  std::atomic<int> clients{0}, clients_peak{0};

  LiveServerCounters counters() const {
    LiveServerCounters c;
    c.requests = requests;
    c.not_found = not_found;
    c.clients_refused = refused;
    c.clients_dropped = dropped;
    c.events_sent = events_sent;
    c.snapshots_read = snapshots_read;
    c.clients_now = clients;
    c.clients_peak = clients_peak;
    return c;
  }

  void routes();
  void serve_events(httplib::Response& res);
  void broadcast_loop();
};

void LiveServer::Impl::routes() {
  const auto asset = [this](std::string_view body, const char* type) {
    return [this, body, type](const httplib::Request&, httplib::Response& res) {
      ++requests;
      res.set_content(body.data(), body.size(), type);
    };
  };
  http.Get("/", asset(kLiveIndexHtml, "text/html; charset=utf-8"));
  http.Get("/live.js", asset(kLiveJs, "text/javascript; charset=utf-8"));
  http.Get("/live.css", asset(kLiveCss, "text/css; charset=utf-8"));
  // Browsers ask for an icon on their own; none is served, without counting it as not found.
  http.Get("/favicon.ico", [this](const httplib::Request&, httplib::Response& res) {
    ++requests;
    res.status = 204;
  });
  const std::string scene_text = scene_json(scene);
  http.Get("/api/scene", [this, scene_text](const httplib::Request&, httplib::Response& res) {
    ++requests;
    res.set_content(scene_text, "application/json");
  });
  http.Get("/api/snapshot", [this](const httplib::Request&, httplib::Response& res) {
    ++requests;
    std::shared_ptr<const std::string> text;
    {
      std::lock_guard lock(mutex);
      text = latest_json;
    }
    res.set_content(text ? *text : std::string("{\"publication\":0}"), "application/json");
  });
  http.Get("/events", [this](const httplib::Request&, httplib::Response& res) {
    ++requests;
    serve_events(res);
  });
  http.set_error_handler(httplib::Server::HandlerWithResponse(
      [this](const httplib::Request& req, httplib::Response& res) {
        if (res.status != 404) return httplib::Server::HandlerResponse::Unhandled;
        ++not_found;
        res.set_content("storetrack live view: no page '" + req.path +
                            "' (pages: /, /api/scene, /api/snapshot, /events)\n",
                        "text/plain; charset=utf-8");
        return httplib::Server::HandlerResponse::Handled;
      }));
  http.set_default_headers({{"Cache-Control", "no-store"}, {"X-Content-Type-Options", "nosniff"}});
}

// One event stream: the newest snapshot at each broadcast, never a queue (a slow client skips
// snapshots); a client that takes nothing for the write timeout is dropped.
void LiveServer::Impl::serve_events(httplib::Response& res) {
  const int now = ++clients;
  if (now > config.max_clients) {
    --clients;
    ++refused;
    res.status = 503;
    res.set_content("storetrack live view: " + std::to_string(config.max_clients) +
                        " clients already connected (the most it serves)\n",
                    "text/plain; charset=utf-8");
    return;
  }
  int peak = clients_peak;
  while (now > peak && !clients_peak.compare_exchange_weak(peak, now)) {
  }
  auto last_seq = std::make_shared<std::uint64_t>(0);
  auto greeted = std::make_shared<bool>(false);
  res.set_chunked_content_provider(
      "text/event-stream",
      [this, last_seq, greeted](std::size_t, httplib::DataSink& sink) {
        if (!*greeted) {
          *greeted = true;
          static constexpr char kRetry[] = "retry: 1000\n\n";  // reconnect after 1 s
          return sink.write(kRetry, sizeof kRetry - 1);
        }
        static const std::string kKeepAlive = ": keep-alive\n\n";
        std::shared_ptr<const std::string> ev;
        {
          std::unique_lock lock(mutex);
          changed.wait_for(lock, std::chrono::seconds(1),
                           [&] { return stopping.load() || event_seq != *last_seq; });
          if (stopping) return false;
          if (event_seq != *last_seq) {
            ev = event;
            *last_seq = event_seq;
          }
        }
        const std::string& text = ev ? *ev : kKeepAlive;
        if (!sink.write(text.data(), text.size())) {
          ++dropped;  // stalled or gone: the write timed out or failed
          return false;
        }
        if (ev) ++events_sent;
        return true;
      },
      [this](bool) { --clients; });
}

void LiveServer::Impl::broadcast_loop() {
  lower_this_thread(config.worker_nice);
  const auto period = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
      std::chrono::duration<double>(1.0 / config.update_hz));
  auto next = std::chrono::steady_clock::now();
  while (!stopping) {
    if (publisher.take()) {
      ++snapshots_read;
      auto text =
          std::make_shared<const std::string>(snapshot_json(publisher.front(), scene, counters()));
      auto ev = std::make_shared<const std::string>("event: snapshot\ndata: " + *text + "\n\n");
      {
        std::lock_guard lock(mutex);
        latest_json = std::move(text);
        event = std::move(ev);
        ++event_seq;
      }
      changed.notify_all();
    }
    next += period;
    std::unique_lock lock(mutex);
    changed.wait_until(lock, next, [&] { return stopping.load(); });
  }
}

LiveServer::LiveServer(const LiveServerConfig& config, LiveScene scene, LivePublisher& publisher)
    : impl_(std::make_unique<Impl>(config, std::move(scene), publisher)) {
  if (config.max_clients < 1 || config.max_clients > 256)
    throw std::invalid_argument("live view: max_clients " + std::to_string(config.max_clients) +
                                " outside 1..256");
  if (!(config.update_hz >= 10 && config.update_hz <= 50))
    throw std::invalid_argument("live view: update rate outside 10..50 Hz");
  if (!(config.write_timeout_s > 0 && config.write_timeout_s <= 10))
    throw std::invalid_argument("live view: write timeout outside (0, 10] s");
}

LiveServer::~LiveServer() {
  stop();
}

void LiveServer::start() {
  Impl& m = *impl_;
  if (m.started) return;
  const LiveServerConfig& c = m.config;
  m.routes();
  // Workers: one per event stream plus a few for the page's other requests; a request that
  // does not arrive within the read timeout frees its worker.
  const std::size_t workers = static_cast<std::size_t>(c.max_clients) + 4;
  m.http.new_task_queue = [workers] { return new httplib::ThreadPool(workers); };
  // One request per connection: a worker never sits on an idle keep-alive connection while
  // other clients wait (the page makes five requests; an event stream is one long request).
  m.http.set_keep_alive_max_count(1);
  m.http.set_keep_alive_timeout(1);
  m.http.set_read_timeout(2, 0);
  const auto timeout_us = static_cast<long>(c.write_timeout_s * 1e6);
  m.http.set_write_timeout(timeout_us / 1'000'000, timeout_us % 1'000'000);
  m.http.set_payload_max_length(4096);  // requests carry no body
  // A small send buffer (accepted sockets inherit the listener's), so a stalled client fills it
  // within seconds and is dropped by the write timeout instead of buffering for minutes.
  const int send_buffer = c.socket_send_buffer > 0 ? c.socket_send_buffer : 64 * 1024;
  int listening_socket = -1;
  m.http.set_socket_options([send_buffer, &listening_socket](int sock) {
    int yes = 1;
    ::setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof yes);
    ::setsockopt(sock, SOL_SOCKET, SO_SNDBUF, &send_buffer, sizeof send_buffer);
    listening_socket = sock;
  });
  errno = 0;
  const std::string where = c.address.host + ":" + std::to_string(c.address.port);
  if (c.address.port == 0) {
    m.bound_port = m.http.bind_to_any_port(c.address.host);
  } else {
    m.bound_port = m.http.bind_to_port(c.address.host, c.address.port) ? c.address.port : -1;
  }
  if (m.bound_port <= 0) {
    const int err = errno;
    throw std::runtime_error("live view: cannot listen on " + where + ": " +
                             (err ? std::strerror(err) : "bind failed") +
                             " (an address of this machine and a free port are needed)");
  }
  // httplib 0.11 listens with a backlog of 5: a burst of connections (a browser opens six at
  // once; the bad-input test a hundred) overflowed it, and the kernel dropped the overflow's
  // handshakes. listen() again on the bound socket sets a backlog the burst fits in.
  if (listening_socket >= 0) (void)::listen(listening_socket, 256);
  m.listener = std::thread([&m] {
    lower_this_thread(m.config.worker_nice);
    m.http.listen_after_bind();
  });
  m.broadcaster = std::thread([&m] { m.broadcast_loop(); });
  m.started = true;
  // httplib's stop() does nothing before its loop runs: wait for it, so stop() always ends it.
  for (int i = 0; i < 2000 && !m.http.is_running(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
}

void LiveServer::stop() {
  Impl& m = *impl_;
  if (!m.started) return;
  m.stopping = true;
  m.changed.notify_all();
  m.http.stop();
  if (m.listener.joinable()) m.listener.join();
  if (m.broadcaster.joinable()) m.broadcaster.join();
  m.started = false;
}

std::string LiveServer::url() const {
  return "http://" + impl_->config.address.host + ":" + std::to_string(impl_->bound_port) + "/";
}

int LiveServer::port() const {
  return impl_->bound_port;
}

LiveServerCounters LiveServer::counters() const {
  return impl_->counters();
}

}  // namespace storetrack::live
