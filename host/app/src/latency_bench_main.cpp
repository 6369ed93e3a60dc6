// storetrack-host-latency-bench: end-to-end latency of storetrack-host, measured from outside.
// Starts storetrack-host as a child process, plays a scenario's observations (storetrack-sim's
// observations.udp, looped with continuing trigger sequence and time) at the frame rate over
// loopback UDP, and receives the host's iNET-X stream. Latency of an exposure = time its iNET-X
// packet is received - time the LAST observation of that exposure was sent (CLOCK_MONOTONIC,
// same machine), so it includes both loopback hops. Prints p50/p99/max and writes JSON.
//
// With --live-clients / --live-stalled the host also serves its live page (--live 127.0.0.1:0)
// to that many readers and stalled clients (live_bench_clients.hpp); --compare N runs the host
// N times without clients and N times with them, alternately, and sets the p99 difference
// against the run-to-run spread (issue 32: the live page must not reach the real-time path).
// Alternating within one invocation matters on a shared machine: the load of the others moves
// every figure, and runs minutes apart would compare the load rather than the clients.
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <fstream>
#include <initializer_list>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>
#include "live_bench_clients.hpp"
#include "storetrack/cli/command_line.hpp"

#include "storetrack/msg/udp_codec.hpp"

namespace st = storetrack;

namespace {

using Exposure = std::vector<st::msg::MarkObservations>;

struct BenchOptions {
  std::string host_bin, setup_dir, replay, json_out, ch10_path;
  double fps = 400, seconds = 10;
  int port = 47300, inetx_port = 47301;
  bool live = false;
  int live_clients = 0, live_stalled = 0;
  int compare_rounds = 0;
};

// What the host serves during one run: its live page or not, and the clients connected to it.
struct LiveLoad {
  bool live = false;
  int readers = 0, stalled = 0;

  bool has_clients() const { return readers + stalled > 0; }
  std::string label() const {
    if (!live) return "no live page";
    if (!has_clients()) return "live, 0 clients";
    return "live, " + std::to_string(readers) + " readers + " + std::to_string(stalled) +
           " stalled";
  }
};

struct RunResult {
  LiveLoad load;
  std::vector<std::int64_t> latencies_ns;
  int exposures_without_packet = 0;
  st::hostapp::LiveClientCounts clients;
  nlohmann::json host_stats;  // the host's --stats-json; null when it wrote none
  bool host_exit_ok = false;
  bool live_url_read = true;
};

std::int64_t mono_now() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

double percentile(std::vector<std::int64_t> v, double q) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  const auto rank =
      static_cast<std::size_t>(std::max(1.0, std::ceil(q * static_cast<double>(v.size()))));
  return static_cast<double>(v[rank - 1]);
}

double median(std::vector<double> v) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  const std::size_t m = v.size() / 2;
  return v.size() % 2 ? v[m] : 0.5 * (v[m - 1] + v[m]);
}

// Observations grouped by exposure, in file order (storetrack-sim's length-prefixed datagrams).
std::vector<Exposure> read_exposures(const std::string& path) {
  std::vector<Exposure> exposures;
  std::ifstream in(path, std::ios::binary);
  std::vector<std::uint8_t> d;
  st::msg::AnyMessage any;
  std::uint32_t last_seq = 0;
  for (;;) {
    std::uint8_t p[4];
    if (!in.read(reinterpret_cast<char*>(p), 4)) break;
    const std::uint32_t len = (std::uint32_t{p[0]} << 24) | (std::uint32_t{p[1]} << 16) |
                              (std::uint32_t{p[2]} << 8) | p[3];
    if (len > 65536) return {};
    d.resize(len);
    if (!in.read(reinterpret_cast<char*>(d.data()), len)) break;
    if (st::msg::decode_datagram(d, any) != st::msg::DecodeError::kNone) continue;
    const auto* o = std::get_if<st::msg::MarkObservations>(&any);
    if (!o) continue;
    if (exposures.empty() || o->trigger_seq != last_seq) exposures.emplace_back();
    last_seq = o->trigger_seq;
    exposures.back().push_back(*o);
  }
  return exposures;
}

// The scenario played in a loop: exposure k is exposures[k % size] with its trigger sequence
// and time continued, so the host sees one unbroken run however short the scenario is.
struct Replay {
  std::vector<Exposure> exposures;
  std::int64_t period_ns = 0, loop_tai_ns = 0;
  int total = 0;
  std::uint32_t first_seq = 0;
  int warmup = 0;  // exposures not counted: page faults, tracking start
};

Replay make_replay(std::vector<Exposure> exposures, double fps, double seconds) {
  Replay r;
  r.period_ns = static_cast<std::int64_t>(1e9 / fps);
  r.loop_tai_ns = exposures.back()[0].exposure_start_tai_ns -
                  exposures.front()[0].exposure_start_tai_ns + r.period_ns;
  r.total = static_cast<int>(seconds * fps);
  r.first_seq = exposures.front()[0].trigger_seq;
  r.warmup = static_cast<int>(0.5 * fps);
  r.exposures = std::move(exposures);
  return r;
}

int udp_socket_bound(int port) {
  const int fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  inet_pton(AF_INET, "127.0.0.1", &a.sin_addr);
  if (bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    close(fd);
    return -1;
  }
  return fd;
}

// Receives the host's iNET-X stream and stamps each exposure's arrival (index k = its trigger
// sequence - the replay's first). Bound before the host starts, so no packet is missed.
class InetxReceiver {
 public:
  InetxReceiver(int port, const Replay& replay)
      : fd_(udp_socket_bound(port)),
        first_seq_(replay.first_seq),
        arrivals_(static_cast<std::size_t>(replay.total), 0) {
    if (fd_ >= 0) thread_ = std::thread([this] { receive_loop(); });
  }
  ~InetxReceiver() {
    stop();
    if (fd_ >= 0) close(fd_);
  }
  bool ok() const { return fd_ >= 0; }
  void stop() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }
  const std::vector<std::int64_t>& arrivals() const { return arrivals_; }

 private:
  void receive_loop() {
    std::array<std::uint8_t, 2048> buf{};
    while (!stop_) {
      pollfd p{fd_, POLLIN, 0};
      if (poll(&p, 1, 50) <= 0) continue;
      const ssize_t n = recv(fd_, buf.data(), buf.size(), 0);
      const std::int64_t now = mono_now();
      if (n < 28 + 12) continue;
      const std::uint8_t* b = buf.data() + 28 + 8;  // FTI parameter block: trigger_seq at 8
      const std::uint32_t seq = (std::uint32_t{b[0]} << 24) | (std::uint32_t{b[1]} << 16) |
                                (std::uint32_t{b[2]} << 8) | b[3];
      const std::uint32_t k = seq - first_seq_;
      if (k < arrivals_.size()) arrivals_[k] = now;
    }
  }

  int fd_;
  std::uint32_t first_seq_;
  std::vector<std::int64_t> arrivals_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

std::string store_envelope_path(const BenchOptions& o) {
  return o.setup_dir + "/store_envelope.json";
}

bool has_store_envelope(const BenchOptions& o) {
  return std::ifstream(store_envelope_path(o)).good();
}

std::vector<std::string> host_arguments(const BenchOptions& o, const LiveLoad& load,
                                        const std::string& stats_path) {
  const std::string& s = o.setup_dir;
  std::vector<std::string> args = {o.host_bin};
  const auto add = [&](std::initializer_list<std::string> more) { args.insert(args.end(), more); };
  add({"--calibration", s + "/rig_calibration.json", "--pylon-survey", s + "/pylon_survey.json"});
  add({"--store-survey", s + "/store_survey.json", "--initial-marks", s + "/initial_marks.json"});
  add({"--udp-port", std::to_string(o.port), "--udp-bind", "127.0.0.1"});
  add({"--inetx", "127.0.0.1:" + std::to_string(o.inetx_port), "--stats-json", stats_path});
  add({"--idle-exit-s", "1", "--log-level", "warn"});
  if (!o.ch10_path.empty()) add({"--ch10", o.ch10_path, "--csv", o.ch10_path + ".csv"});
  if (load.live) {
    // Port 0: any free port, read back from the URL the host prints. Room for every client
    // plus a stalled one's reconnection before the server has counted its drop.
    const int max_clients = std::max(24, load.readers + load.stalled + 4);
    add({"--live", "127.0.0.1:0", "--live-max-clients", std::to_string(max_clients)});
    // The store envelope tools/sim_setup.py wrote: the events then carry the coverage overlay
    // (docs/live-view.md), as they do in a test point.
    if (has_store_envelope(o)) add({"--config", store_envelope_path(o)});
  }
  return args;
}

// storetrack-host as a child process. Its stdout comes through a pipe that a thread reads to
// the end: the live page's URL is on it, and a pipe nobody drained could block the host's
// summary at exit. The rest of the output is discarded (the figures come from --stats-json).
class HostChild {
 public:
  explicit HostChild(std::vector<std::string> args) {
    // argv is built before fork(): the bench has threads, so the child may not allocate.
    std::vector<char*> argv;
    for (auto& arg : args)
      argv.push_back(arg.data());
    argv.push_back(nullptr);
    int out[2];
    if (pipe2(out, O_CLOEXEC) != 0) return;
    pid_ = fork();
    if (pid_ == 0) exec_host(argv, out[1]);
    close(out[1]);
    if (pid_ < 0) {
      close(out[0]);
      return;
    }
    reader_ = std::thread([this, fd = out[0]] { read_output(fd); });
  }
  ~HostChild() { wait(); }
  bool started() const { return pid_ > 0; }

  std::optional<std::string> wait_for_live_url(double timeout_s) {
    std::unique_lock lock(mutex_);
    changed_.wait_for(lock, std::chrono::duration<double>(timeout_s),
                      [&] { return url_.has_value() || eof_; });
    return url_;
  }
  void terminate() {
    if (pid_ > 0) kill(pid_, SIGTERM);
  }
  /// True when the host exited with status 0.
  bool wait() {
    if (pid_ > 0) {
      waitpid(pid_, &status_, 0);
      pid_ = 0;
    }
    if (reader_.joinable()) reader_.join();
    return WIFEXITED(status_) && WEXITSTATUS(status_) == 0;
  }

 private:
  [[noreturn]] static void exec_host(const std::vector<char*>& argv, int stdout_fd) {
    dup2(stdout_fd, STDOUT_FILENO);  // the copy is not close-on-exec
    execv(argv[0], argv.data());
    std::_Exit(127);
  }

  void read_output(int fd) {
    static constexpr std::string_view kPrefix = "storetrack-host: live view at ";
    std::string line;
    char c = 0;
    while (read(fd, &c, 1) == 1) {  // a few lines in all: byte by byte is fine
      if (c != '\n') {
        line += c;
        continue;
      }
      if (line.rfind(kPrefix, 0) == 0) {
        std::lock_guard lock(mutex_);
        url_ = line.substr(kPrefix.size());
        changed_.notify_all();
      }
      line.clear();
    }
    close(fd);
    std::lock_guard lock(mutex_);
    eof_ = true;
    changed_.notify_all();
  }

  pid_t pid_ = -1;
  int status_ = -1;
  std::thread reader_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::optional<std::string> url_;
  bool eof_ = false;
};

// Sends the replay at the frame rate; returns when each exposure's last observation was sent.
std::vector<std::int64_t> send_at_frame_rate(const Replay& r, int port) {
  const int tx = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  sockaddr_in dst{};
  dst.sin_family = AF_INET;
  dst.sin_port = htons(static_cast<std::uint16_t>(port));
  inet_pton(AF_INET, "127.0.0.1", &dst.sin_addr);
  std::array<std::uint8_t, st::msg::kMaxDatagramBytes> buf{};
  std::vector<std::int64_t> sent(static_cast<std::size_t>(r.total), 0);
  const std::int64_t t0 = mono_now() + 10'000'000;
  std::uint32_t dseq = 0;
  for (int k = 0; k < r.total; ++k) {
    const std::int64_t due = t0 + k * r.period_ns;
    timespec ts{static_cast<time_t>(due / 1'000'000'000), static_cast<long>(due % 1'000'000'000)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
    const Exposure& group = r.exposures[static_cast<std::size_t>(k) % r.exposures.size()];
    const std::int64_t loop = k / static_cast<int>(r.exposures.size());
    for (auto o : group) {
      o.trigger_seq = r.first_seq + static_cast<std::uint32_t>(k);
      o.exposure_start_tai_ns += loop * r.loop_tai_ns;
      const int n = st::msg::encode_datagram(o, buf, dseq++);
      sendto(tx, buf.data(), static_cast<std::size_t>(n), 0, reinterpret_cast<sockaddr*>(&dst),
             sizeof dst);
    }
    sent[static_cast<std::size_t>(k)] = mono_now();
  }
  close(tx);
  return sent;
}

void collect_latencies(const Replay& r, const std::vector<std::int64_t>& sent,
                       const std::vector<std::int64_t>& received, RunResult& result) {
  for (int k = r.warmup; k < r.total; ++k) {
    const auto i = static_cast<std::size_t>(k);
    if (received[i] == 0) {
      ++result.exposures_without_packet;
      continue;
    }
    result.latencies_ns.push_back(received[i] - sent[i]);
  }
}

nlohmann::json read_and_remove_json(const std::string& path) {
  std::ifstream in(path);
  if (!in) return nullptr;
  nlohmann::json j;
  in >> j;
  std::remove(path.c_str());
  return j;
}

// Connects the run's live clients once the host printed its URL; null when there are none.
std::unique_ptr<st::hostapp::LiveClients> connect_live_clients(HostChild& host,
                                                               const LiveLoad& load,
                                                               RunResult& result) {
  if (!load.live) return nullptr;
  const std::optional<std::string> url = host.wait_for_live_url(10.0);
  const auto endpoint = url ? st::hostapp::parse_live_url(*url) : std::nullopt;
  if (!endpoint) {
    result.live_url_read = false;
    return nullptr;
  }
  if (!load.has_clients()) return nullptr;
  auto clients = std::make_unique<st::hostapp::LiveClients>(*endpoint, load.readers, load.stalled);
  clients->wait_for_responses(3.0);
  return clients;
}

RunResult run_once(const BenchOptions& o, const Replay& replay, const LiveLoad& load,
                   int run_index) {
  RunResult result;
  result.load = load;
  InetxReceiver receiver(o.inetx_port, replay);
  if (!receiver.ok()) {
    std::perror("latency-bench: bind iNET-X port");
    return result;
  }
  const std::string stats_path = "/tmp/storetrack-latency-bench-" + std::to_string(getpid()) + "-" +
                                 std::to_string(run_index) + ".json";
  HostChild host(host_arguments(o, load, stats_path));
  if (!host.started()) return result;
  usleep(700'000);  // host start-up (calibration, surveys)
  auto clients = connect_live_clients(host, load, result);
  if (!result.live_url_read) {
    host.terminate();
    host.wait();
    return result;
  }
  const std::vector<std::int64_t> sent = send_at_frame_rate(replay, o.port);
  usleep(300'000);
  if (clients) result.clients = clients->stop();  // before the host ends their streams
  receiver.stop();
  result.host_exit_ok = host.wait();  // exits after 1 s without input
  collect_latencies(replay, sent, receiver.arrivals(), result);
  result.host_stats = read_and_remove_json(stats_path);
  return result;
}

double p_us(const RunResult& r, double q) {
  return percentile(r.latencies_ns, q) * 1e-3;
}
double max_us(const RunResult& r) {
  if (r.latencies_ns.empty()) return NAN;
  return static_cast<double>(*std::max_element(r.latencies_ns.begin(), r.latencies_ns.end())) *
         1e-3;
}

// The host's own figure (receive of the last observation -> iNET-X sent), for comparison.
double host_internal_p99_us(const RunResult& r) {
  if (r.host_stats.is_null()) return NAN;
  return r.host_stats["latency"]["last_observation_to_inetx_complete_exposures"]["p99_us"]
      .get<double>();
}

nlohmann::json clients_json(const st::hostapp::LiveClientCounts& c) {
  return {{"readers", c.readers},
          {"readers_streaming", c.readers_streaming},
          {"readers_refused", c.readers_refused},
          {"readers_closed_early", c.readers_closed_early},
          {"events_received_total", c.events_total},
          {"events_received_min_per_reader", c.events_min},
          {"events_received_max_per_reader", c.events_max},
          {"stalled", c.stalled},
          {"stalled_connections", c.stalled_connections},
          {"stalled_unread_bytes_max", c.stalled_unread_bytes_max}};
}

nlohmann::json run_json(const BenchOptions& o, const Replay& replay, const RunResult& r) {
  nlohmann::json j;
  j["configuration"] = r.load.label();
  j["fps"] = o.fps;
  j["exposures_measured"] = r.latencies_ns.size();
  j["exposures_without_packet"] = r.exposures_without_packet;
  j["p50_us"] = p_us(r, 0.5);
  j["p99_us"] = p_us(r, 0.99);
  j["max_us"] = max_us(r);
  j["cameras_per_exposure"] = replay.exposures.front().size();
  j["marks_per_exposure_camera0"] = replay.exposures.front()[0].mark_count;
  j["host_writes_chapter10_and_csv"] = !o.ch10_path.empty();
  j["host_exit_ok"] = r.host_exit_ok;
  if (r.load.live) {
    j["live_clients"] = clients_json(r.clients);
    j["live_coverage_overlay"] = has_store_envelope(o);
  }
  if (!r.host_stats.is_null()) {
    j["host_internal_latency"] = r.host_stats["latency"];
    j["host_valid_samples"] = r.host_stats["valid_samples"];
    j["host_exposures"] = r.host_stats["exposures_processed"];
    if (r.host_stats.contains("live")) j["host_live"] = r.host_stats["live"];
  }
  return j;
}

// A run with clients counts only if they were really there: every reader streamed and
// received events through the run, and the stalled clients' buffers filled (the server felt
// the stall). Else the comparison would be against nothing.
bool clients_were_served(const RunResult& r) {
  if (!r.load.has_clients()) return true;
  const auto& c = r.clients;
  return c.readers_streaming == c.readers && c.readers_closed_early == 0 &&
         (c.readers == 0 || c.events_min > 0) && (c.stalled == 0 || c.stalled_unread_bytes_max > 0);
}

bool run_ok(const RunResult& r) {
  return r.host_exit_ok && r.live_url_read && !r.latencies_ns.empty() && clients_were_served(r);
}

void print_run_header() {
  std::printf("%-3s  %-30s %8s %8s %8s %9s %5s  %-14s %s\n", "run", "configuration", "p50 us",
              "p99 us", "max us", "host p99", "lost", "events/reader",
              "stalled: opened, most unread KiB; server dropped");
}

// The host's own count of streams it ended early (stalled, or closed by the client).
long long host_live_clients_dropped(const RunResult& r) {
  if (r.host_stats.is_null() || !r.host_stats.contains("live")) return -1;
  return r.host_stats["live"]["clients_dropped"].get<long long>();
}

void print_run_line(int index, const RunResult& r) {
  const auto& c = r.clients;
  char events[64] = "-", stalled[96] = "-";
  if (c.readers > 0)
    std::snprintf(events, sizeof events, "%llu-%llu", static_cast<unsigned long long>(c.events_min),
                  static_cast<unsigned long long>(c.events_max));
  if (c.stalled > 0)
    std::snprintf(stalled, sizeof stalled, "%d, %.0f; %lld", c.stalled_connections,
                  static_cast<double>(c.stalled_unread_bytes_max) / 1024.0,
                  host_live_clients_dropped(r));
  std::printf("%-3d  %-30s %8.1f %8.1f %8.1f %9.1f %5d  %-14s %s%s\n", index,
              r.load.label().c_str(), p_us(r, 0.5), p_us(r, 0.99), max_us(r),
              host_internal_p99_us(r), r.exposures_without_packet, events, stalled,
              run_ok(r) ? "" : "  (FAILED: see the JSON)");
  std::fflush(stdout);
}

struct P99Summary {
  double median = NAN, min = NAN, max = NAN;
  double spread() const { return max - min; }
};

P99Summary summarize_p99(const std::vector<RunResult>& runs, bool with_clients) {
  std::vector<double> p99;
  for (const RunResult& r : runs)
    if (r.load.has_clients() == with_clients) p99.push_back(p_us(r, 0.99));
  P99Summary s;
  if (p99.empty()) return s;
  s.median = median(p99);
  s.min = *std::min_element(p99.begin(), p99.end());
  s.max = *std::max_element(p99.begin(), p99.end());
  return s;
}

// The comparison, within this one invocation: the medians of p99 without and with clients,
// their ratio, each round's ratio (its two runs were next to each other in time), and whether
// the difference of the medians lies within the run-to-run spread (the larger of the two
// configurations' p99 max - min).
nlohmann::json compare(const std::vector<RunResult>& runs) {
  const P99Summary base = summarize_p99(runs, false), loaded = summarize_p99(runs, true);
  std::vector<double> round_ratios;
  for (std::size_t i = 0; i + 1 < runs.size(); i += 2)
    round_ratios.push_back(p_us(runs[i + 1], 0.99) / p_us(runs[i], 0.99));
  const double spread = std::max(base.spread(), loaded.spread());
  const double difference = loaded.median - base.median;
  const auto summary_json = [](const P99Summary& s) {
    return nlohmann::json{
        {"p99_median_us", s.median}, {"p99_min_us", s.min}, {"p99_max_us", s.max}};
  };
  return {{"without_clients", summary_json(base)},
          {"with_clients", summary_json(loaded)},
          {"p99_ratio_of_medians", loaded.median / base.median},
          {"p99_ratio_per_round", round_ratios},
          {"p99_difference_of_medians_us", difference},
          {"run_to_run_spread_us", spread},
          {"difference_within_spread", std::abs(difference) <= spread}};
}

void print_comparison(const nlohmann::json& c, const std::string& base_label,
                      const std::string& loaded_label) {
  const auto line = [](const std::string& label, const nlohmann::json& s) {
    std::printf("%-30s p99 median %8.1f us, min-max %.1f-%.1f us\n", label.c_str(),
                s["p99_median_us"].get<double>(), s["p99_min_us"].get<double>(),
                s["p99_max_us"].get<double>());
  };
  std::printf("\n");
  line(base_label, c["without_clients"]);
  line(loaded_label, c["with_clients"]);
  std::printf("p99 ratio, with / without clients: %.3f (medians); per round:",
              c["p99_ratio_of_medians"].get<double>());
  for (const auto& r : c["p99_ratio_per_round"])
    std::printf(" %.3f", r.get<double>());
  std::printf(
      "\ndifference of the medians %+.1f us; run-to-run spread %.1f us: %s\n",
      c["p99_difference_of_medians_us"].get<double>(), c["run_to_run_spread_us"].get<double>(),
      c["difference_within_spread"].get<bool>() ? "within the spread" : "OUTSIDE the spread");
  if (c["p99_ratio_per_round"].size() < 3)
    std::printf("(fewer than 3 rounds: the spread of so few runs says little; use --compare 3+)\n");
}

// --compare N: N rounds of (live page without clients, live page with the clients), one
// invocation, the two configurations alternating so that both see the same machine.
int run_comparison(const BenchOptions& o, const Replay& replay) {
  const LiveLoad base{true, 0, 0}, loaded{true, o.live_clients, o.live_stalled};
  std::vector<RunResult> runs;
  bool all_ok = true;
  print_run_header();
  for (int round = 0; round < o.compare_rounds; ++round) {
    for (const LiveLoad& load : {base, loaded}) {
      runs.push_back(run_once(o, replay, load, static_cast<int>(runs.size())));
      print_run_line(static_cast<int>(runs.size()), runs.back());
      all_ok = all_ok && run_ok(runs.back());
    }
  }
  const nlohmann::json comparison = compare(runs);
  print_comparison(comparison, base.label(), loaded.label());
  if (!o.json_out.empty()) {
    nlohmann::json j;
    for (const RunResult& r : runs)
      j["runs"].push_back(run_json(o, replay, r));
    j["comparison"] = comparison;
    std::ofstream(o.json_out) << j.dump(2) << "\n";
  }
  return all_ok ? 0 : 1;
}

int run_single(const BenchOptions& o, const Replay& replay) {
  const LiveLoad load{o.live || o.live_clients + o.live_stalled > 0, o.live_clients,
                      o.live_stalled};
  const RunResult r = run_once(o, replay, load, 0);
  const nlohmann::json j = run_json(o, replay, r);
  std::printf("%s\n", j.dump(2).c_str());
  if (!o.json_out.empty()) std::ofstream(o.json_out) << j.dump(2) << "\n";
  return run_ok(r) ? 0 : 1;
}

int parse_options(int argc, char** argv, BenchOptions& o) {
  storetrack::cli::Command app{
      "storetrack-host-latency-bench: last observation -> iNET-X packet, p99"};
  app.option("--host", o.host_bin, "storetrack-host executable").required().existing_file();
  app.option("--setup", o.setup_dir,
             "Directory with rig_calibration.json, pylon_survey.json, "
             "store_survey.json, initial_marks.json")
      .required()
      .existing_directory();
  app.option("--replay", o.replay, "storetrack-sim observations.udp").required().existing_file();
  app.option("--fps", o.fps, "Exposure rate").positive();
  app.option("--seconds", o.seconds, "Duration of the measurement").positive();
  app.option("--port", o.port, "UDP port of the host's input");
  app.option("--inetx-port", o.inetx_port, "UDP port the host sends iNET-X to");
  app.option("--json", o.json_out, "Write the results as JSON");
  app.option("--ch10", o.ch10_path,
             "Let the host also write this Chapter 10 file (fdatasync per packet) and a CSV");
  app.flag("--live", o.live, "Let the host serve its live page (127.0.0.1, any free port)");
  app.option("--live-clients", o.live_clients,
             "Live page readers: GET /events, read continuously (implies --live)")
      .range(0, 200);
  app.option("--live-stalled", o.live_stalled,
             "Live page clients that send GET /events and never read (implies --live)")
      .range(0, 200);
  app.option("--compare", o.compare_rounds,
             "Run N rounds of (live page, 0 clients) and (live page, the clients given), "
             "alternately, and compare their p99")
      .range(0, 100);
  if (const int rc = app.parse(argc, argv); rc >= 0) return rc;
  if (o.compare_rounds > 0 && o.live_clients + o.live_stalled == 0) {
    std::fprintf(stderr, "latency-bench: --compare needs --live-clients or --live-stalled\n");
    return st::cli::kExitUsage;
  }
  return -1;
}

}  // namespace

int main(int argc, char** argv) {
  BenchOptions o;
  if (const int rc = parse_options(argc, argv, o); rc >= 0) return rc;
  std::vector<Exposure> exposures = read_exposures(o.replay);
  if (exposures.size() < 2) {
    std::fprintf(stderr, "latency-bench: %s holds no observations\n", o.replay.c_str());
    return 2;
  }
  const Replay replay = make_replay(std::move(exposures), o.fps, o.seconds);
  return o.compare_rounds > 0 ? run_comparison(o, replay) : run_single(o, replay);
}
