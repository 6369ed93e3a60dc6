// storetrack-host-latency-bench: end-to-end latency of storetrack-host, measured from outside.
// Starts storetrack-host as a child process, plays a scenario's observations (storetrack-sim's
// observations.udp, looped with continuing trigger sequence and time) at the frame rate over
// loopback UDP, and receives the host's iNET-X stream. Latency of an exposure = time its iNET-X
// packet is received - time the LAST observation of that exposure was sent (CLOCK_MONOTONIC,
// same machine), so it includes both loopback hops. Prints p50/p99/max and writes JSON.
#include <arpa/inet.h>
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
#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>
#include "storetrack/cli/command_line.hpp"

#include "storetrack/msg/udp_codec.hpp"

namespace st = storetrack;

namespace {

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

}  // namespace

int main(int argc, char** argv) {
  storetrack::cli::Command app{
      "storetrack-host-latency-bench: last observation -> iNET-X packet, p99"};
  std::string host_bin, setup_dir, replay, json_out;
  double fps = 400, seconds = 10;
  int port = 47300, inetx_port = 47301;
  app.option("--host", host_bin, "storetrack-host executable").required().existing_file();
  app.option("--setup", setup_dir,
             "Directory with rig_calibration.json, pylon_survey.json, "
             "store_survey.json, initial_marks.json")
      .required()
      .existing_directory();
  app.option("--replay", replay, "storetrack-sim observations.udp").required().existing_file();
  app.option("--fps", fps, "Exposure rate").positive();
  app.option("--seconds", seconds, "Duration of the measurement").positive();
  app.option("--port", port, "UDP port of the host's input");
  app.option("--inetx-port", inetx_port, "UDP port the host sends iNET-X to");
  app.option("--json", json_out, "Write the results as JSON");
  std::string ch10_path;
  app.option("--ch10", ch10_path,
             "Let the host also write this Chapter 10 file (fdatasync per packet) and a CSV");
  if (const int rc = app.parse(argc, argv); rc >= 0) return rc;

  // Observations grouped by exposure, in file order.
  std::vector<std::vector<st::msg::MarkObservations>> exposures;
  {
    std::ifstream in(replay, std::ios::binary);
    std::vector<std::uint8_t> d;
    st::msg::AnyMessage any;
    std::uint32_t last_seq = 0;
    for (;;) {
      std::uint8_t p[4];
      if (!in.read(reinterpret_cast<char*>(p), 4)) break;
      const std::uint32_t len = (std::uint32_t{p[0]} << 24) | (std::uint32_t{p[1]} << 16) |
                                (std::uint32_t{p[2]} << 8) | p[3];
      if (len > 65536) return 2;
      d.resize(len);
      if (!in.read(reinterpret_cast<char*>(d.data()), len)) break;
      if (st::msg::decode_datagram(d, any) != st::msg::DecodeError::kNone) continue;
      const auto* o = std::get_if<st::msg::MarkObservations>(&any);
      if (!o) continue;
      if (exposures.empty() || o->trigger_seq != last_seq) exposures.emplace_back();
      last_seq = o->trigger_seq;
      exposures.back().push_back(*o);
    }
  }
  if (exposures.size() < 2) {
    std::fprintf(stderr, "latency-bench: %s holds no observations\n", replay.c_str());
    return 2;
  }
  const std::int64_t period_ns = static_cast<std::int64_t>(1e9 / fps);
  const std::int64_t loop_tai_ns = exposures.back()[0].exposure_start_tai_ns -
                                   exposures.front()[0].exposure_start_tai_ns + period_ns;
  const int total = static_cast<int>(seconds * fps);

  // Receiver of the iNET-X stream first, then the host.
  const int rx = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(inetx_port));
  inet_pton(AF_INET, "127.0.0.1", &a.sin_addr);
  if (bind(rx, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    std::perror("latency-bench: bind iNET-X port");
    return 1;
  }
  const std::uint32_t first_seq = exposures.front()[0].trigger_seq;
  std::vector<std::int64_t> t_sent(static_cast<std::size_t>(total), 0),
      t_recv(static_cast<std::size_t>(total), 0);
  std::atomic<bool> stop{false};
  std::thread receiver([&] {
    std::array<std::uint8_t, 2048> buf{};
    while (!stop) {
      pollfd p{rx, POLLIN, 0};
      if (poll(&p, 1, 50) <= 0) continue;
      const ssize_t n = recv(rx, buf.data(), buf.size(), 0);
      const std::int64_t now = mono_now();
      if (n < 28 + 12) continue;
      const std::uint8_t* b = buf.data() + 28 + 8;  // FTI parameter block: trigger_seq at 8
      const std::uint32_t seq = (std::uint32_t{b[0]} << 24) | (std::uint32_t{b[1]} << 16) |
                                (std::uint32_t{b[2]} << 8) | b[3];
      const std::uint32_t k = seq - first_seq;
      if (k < static_cast<std::uint32_t>(total)) t_recv[k] = now;
    }
  });

  const std::string stats_path =
      "/tmp/storetrack-latency-bench-" + std::to_string(getpid()) + ".json";
  const pid_t host = fork();
  if (host == 0) {
    const std::string p = std::to_string(port), q = "127.0.0.1:" + std::to_string(inetx_port);
    const std::string rig = setup_dir + "/rig_calibration.json",
                      py = setup_dir + "/pylon_survey.json", sv = setup_dir + "/store_survey.json",
                      im = setup_dir + "/initial_marks.json";
    std::vector<std::string> args = {
        host_bin,    "--calibration",   rig,   "--pylon-survey", py,         "--store-survey",
        sv,          "--initial-marks", im,    "--udp-port",     p,          "--udp-bind",
        "127.0.0.1", "--inetx",         q,     "--stats-json",   stats_path, "--idle-exit-s",
        "1",         "--log-level",     "warn"};
    if (!ch10_path.empty()) {
      for (const std::string& extra :
           {std::string("--ch10"), ch10_path, std::string("--csv"), ch10_path + ".csv"})
        args.push_back(extra);
    }
    std::vector<char*> argv_c;
    for (auto& arg : args)
      argv_c.push_back(arg.data());
    argv_c.push_back(nullptr);
    execv(host_bin.c_str(), argv_c.data());
    std::_Exit(127);
  }
  usleep(700'000);  // host start-up (calibration, surveys)

  const int tx = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  sockaddr_in dst{};
  dst.sin_family = AF_INET;
  dst.sin_port = htons(static_cast<std::uint16_t>(port));
  inet_pton(AF_INET, "127.0.0.1", &dst.sin_addr);
  std::array<std::uint8_t, st::msg::kMaxDatagramBytes> buf{};
  const std::int64_t t0 = mono_now() + 10'000'000;
  std::uint32_t dseq = 0;
  for (int k = 0; k < total; ++k) {
    const std::int64_t due = t0 + k * period_ns;
    timespec ts{static_cast<time_t>(due / 1'000'000'000), static_cast<long>(due % 1'000'000'000)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
    const auto& group = exposures[static_cast<std::size_t>(k) % exposures.size()];
    const std::int64_t loop = k / static_cast<int>(exposures.size());
    for (auto o : group) {
      o.trigger_seq = first_seq + static_cast<std::uint32_t>(k);
      o.exposure_start_tai_ns += loop * loop_tai_ns;
      const int n = st::msg::encode_datagram(o, buf, dseq++);
      sendto(tx, buf.data(), static_cast<std::size_t>(n), 0, reinterpret_cast<sockaddr*>(&dst),
             sizeof dst);
    }
    t_sent[static_cast<std::size_t>(k)] = mono_now();
  }
  usleep(300'000);
  stop = true;
  receiver.join();
  int status = 0;
  waitpid(host, &status, 0);  // exits after 1 s without input

  std::vector<std::int64_t> lat;
  int lost = 0;
  // The first 0.5 s warm the host up (page faults, tracking start) and are not counted.
  const int warmup = static_cast<int>(0.5 * fps);
  for (int k = warmup; k < total; ++k) {
    if (t_recv[static_cast<std::size_t>(k)] == 0) {
      ++lost;
      continue;
    }
    lat.push_back(t_recv[static_cast<std::size_t>(k)] - t_sent[static_cast<std::size_t>(k)]);
  }
  nlohmann::json j;
  j["fps"] = fps;
  j["exposures_measured"] = lat.size();
  j["exposures_without_packet"] = lost;
  j["p50_us"] = percentile(lat, 0.5) * 1e-3;
  j["p99_us"] = percentile(lat, 0.99) * 1e-3;
  j["max_us"] =
      lat.empty() ? NAN : static_cast<double>(*std::max_element(lat.begin(), lat.end())) * 1e-3;
  j["cameras_per_exposure"] = exposures.front().size();
  j["marks_per_exposure_camera0"] = exposures.front()[0].mark_count;
  j["host_writes_chapter10_and_csv"] = !ch10_path.empty();
  std::ifstream hs(stats_path);
  if (hs) {
    nlohmann::json h;
    hs >> h;
    j["host_internal_latency"] = h["latency"];
    j["host_valid_samples"] = h["valid_samples"];
    j["host_exposures"] = h["exposures_processed"];
    std::remove(stats_path.c_str());
  }
  std::printf("%s\n", j.dump(2).c_str());
  if (!json_out.empty()) std::ofstream(json_out) << j.dump(2) << "\n";
  return WIFEXITED(status) && WEXITSTATUS(status) == 0 ? 0 : 1;
}
