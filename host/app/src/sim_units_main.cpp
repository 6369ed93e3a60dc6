// storetrack-sim-units: a replay/setup helper, NOT a camera unit. The main job
// (tools/testpoint) and its integration test run the real camera-unit program (storetrack-unit
// --source sim) instead; this program remains because tests/rig/guest/can_app.sh uses its
// --write-setup DIR (calibrated rig, surveys, initial mark positions for the host) and it is a
// cheap load generator for host-only experiments. It sends the simulator's fast-mode
// observations (projected marks + centroid noise, no rendering, no centroiding) over UDP or CAN
// FD with the unit's codecs, paced at the scenario's frame rate; with --replay FILE it sends
// storetrack-sim's precomputed observations.udp (u32 big-endian length + datagram).
#include <arpa/inet.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <string>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/msg/canfd_codec.hpp"
#include "storetrack/msg/canfd_linux.hpp"
#include "storetrack/msg/udp_codec.hpp"
#include "storetrack/sim/scenario.hpp"
#include "storetrack/sim/simulator.hpp"

namespace st = storetrack;

namespace {

void sleep_until_mono(std::int64_t t_ns) {
  timespec ts{static_cast<time_t>(t_ns / 1'000'000'000), static_cast<long>(t_ns % 1'000'000'000)};
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

std::int64_t mono_now() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

int write_setup(const st::sim::Simulator& sim, const std::string& dir) {
  st::camera::write_rig_calibration(sim.calibrated_rig(), dir + "/rig_calibration.json");
  st::sim::write_survey(sim.pylon_survey(), dir + "/pylon_survey.json");
  const bool has_store = sim.scenario().has_store();
  st::sim::write_survey(has_store ? sim.store_survey() : sim.pendulum_survey(),
                        dir + "/store_survey.json");
  // Initial mark positions, as the installation survey would give them before the test point:
  // the marks at exposure 0 with 1 mm (1 sigma) survey noise.
  const auto truth = sim.truth(0);
  std::mt19937_64 rng(12345);
  std::normal_distribution<double> noise(0.0, 1e-3);
  nlohmann::json marks = nlohmann::json::array();
  for (const auto& m : truth.marks) {
    marks.push_back(
        {{"id", m.id},
         {"p_w_m", {m.p_w.x() + noise(rng), m.p_w.y() + noise(rng), m.p_w.z() + noise(rng)}}});
  }
  std::ofstream(dir + "/initial_marks.json") << nlohmann::json{{"marks", marks}}.dump(1) << "\n";
  nlohmann::json units = nlohmann::json::array();
  for (const auto& c : sim.scenario().cameras)
    units.push_back({{"camera_id", c.camera_id}, {"unit_id", c.unit_id}});
  std::ofstream(dir + "/setup.json")
      << nlohmann::json{{"num_exposures", sim.num_exposures()},
                        {"frame_rate_hz", sim.scenario().frame_rate_hz},
                        {"cameras", units},
                        {"kind", st::sim::to_string(sim.scenario().kind)}}
             .dump(1)
      << "\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"storetrack-sim-units: the simulator's camera units on UDP / CAN FD"};
  std::string scenario_path, dest = "127.0.0.1:47100", can_if, setup_dir, replay_path;
  std::uint64_t seed = 1;
  int unit = -1, max_exposures = 0;
  double rate_factor = 1.0, loss = 0.0, start_delay_s = 0.0;
  std::int64_t start_at_realtime_ms = 0;
  bool quiet = false;
  app.add_option("--scenario", scenario_path, "Scenario JSON")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--seed", seed, "Simulator seed (every unit and the setup must use the same)");
  app.add_option("--unit", unit, "Unit id to play (its cameras); -1: all cameras");
  app.add_option("--dest", dest, "UDP destination address:port");
  app.add_option("--can", can_if, "Send CAN FD on this SocketCAN interface instead of UDP");
  app.add_option("--rate-factor", rate_factor,
                 "Pacing relative to the frame rate (1 real time, 0 as fast as possible)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--exposures", max_exposures, "Send at most this many exposures");
  app.add_option("--loss", loss, "Drop this fraction of messages (fault injection)")
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--start-at-ms", start_at_realtime_ms,
                 "Start at this CLOCK_REALTIME instant (ms since 1970) so units start together");
  app.add_option("--start-delay-s", start_delay_s, "Wait this long before sending");
  app.add_option("--write-setup", setup_dir,
                 "Write calibration, surveys, initial marks and truth CSVs to DIR and exit");
  app.add_option("--replay", replay_path,
                 "Send the datagrams of storetrack-sim's observations.udp (this unit's cameras)")
      ->check(CLI::ExistingFile);
  app.add_flag("--quiet", quiet, "No summary line");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? 0 : 2;
  }
  st::sim::Scenario scenario;
  try {
    scenario = st::sim::load_scenario(scenario_path);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-sim-units: %s\n", e.what());
    return 2;
  }
  const st::sim::Simulator sim(scenario, seed);
  if (!setup_dir.empty()) {
    try {
      return write_setup(sim, setup_dir);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "storetrack-sim-units: %s\n", e.what());
      return 2;
    }
  }
  std::vector<int> camera_indices;
  for (int i = 0; i < sim.num_cameras(); ++i)
    if (unit < 0 || scenario.cameras[static_cast<std::size_t>(i)].unit_id == unit)
      camera_indices.push_back(i);
  if (camera_indices.empty()) {
    std::fprintf(stderr, "storetrack-sim-units: unit %d has no camera in %s\n", unit,
                 scenario_path.c_str());
    return 2;
  }

  int fd = -1;
  sockaddr_in dst{};
  if (can_if.empty()) {
    const auto colon = dest.rfind(':');
    if (colon == std::string::npos ||
        inet_pton(AF_INET, dest.substr(0, colon).c_str(), &dst.sin_addr) != 1) {
      std::fprintf(stderr, "storetrack-sim-units: --dest '%s': expected a.b.c.d:port\n",
                   dest.c_str());
      return 2;
    }
    dst.sin_family = AF_INET;
    dst.sin_port = htons(static_cast<std::uint16_t>(std::stoi(dest.substr(colon + 1))));
    fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  } else {
    const unsigned index = if_nametoindex(can_if.c_str());
    if (index == 0) {
      std::fprintf(stderr, "storetrack-sim-units: no CAN interface '%s'\n", can_if.c_str());
      return 2;
    }
    fd = socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
    const int on = 1;
    setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on);
    sockaddr_can addr{};
    addr.can_family = AF_CAN;
    addr.can_ifindex = static_cast<int>(index);
    if (bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
      std::fprintf(stderr, "storetrack-sim-units: bind %s: %s\n", can_if.c_str(), strerror(errno));
      return 1;
    }
  }
  if (fd < 0) {
    std::fprintf(stderr, "storetrack-sim-units: socket: %s\n", strerror(errno));
    return 1;
  }

  const int n =
      max_exposures > 0 ? std::min(max_exposures, sim.num_exposures()) : sim.num_exposures();
  // Every message of this unit, per exposure, computed BEFORE sending so the pacing holds.
  std::vector<std::vector<st::msg::MarkObservations>> by_exposure(static_cast<std::size_t>(n));
  if (!replay_path.empty()) {
    std::ifstream in(replay_path, std::ios::binary);
    std::vector<std::uint8_t> datagram;
    const std::uint32_t first_seq = scenario.first_trigger_seq;
    st::msg::AnyMessage any;
    for (;;) {
      std::uint8_t prefix[4];
      if (!in.read(reinterpret_cast<char*>(prefix), 4)) break;
      const std::uint32_t len = (std::uint32_t{prefix[0]} << 24) |
                                (std::uint32_t{prefix[1]} << 16) | (std::uint32_t{prefix[2]} << 8) |
                                prefix[3];
      if (len > 65536) {
        std::fprintf(stderr, "storetrack-sim-units: %s: corrupt length prefix\n",
                     replay_path.c_str());
        return 2;
      }
      datagram.resize(len);
      if (!in.read(reinterpret_cast<char*>(datagram.data()), len)) break;
      if (st::msg::decode_datagram(datagram, any) != st::msg::DecodeError::kNone) continue;
      const auto* o = std::get_if<st::msg::MarkObservations>(&any);
      if (!o || (unit >= 0 && o->unit_id != unit)) continue;
      const std::uint32_t k = o->trigger_seq - first_seq;
      if (k < static_cast<std::uint32_t>(n)) by_exposure[k].push_back(*o);
    }
  } else {
    for (int k = 0; k < n; ++k) {
      for (int ci : camera_indices) {
        by_exposure[static_cast<std::size_t>(k)].emplace_back();
        sim.observe(k, ci, by_exposure[static_cast<std::size_t>(k)].back());
      }
    }
  }
  const double period_ns = 1e9 / scenario.frame_rate_hz;
  std::mt19937_64 rng(seed * 1000 + static_cast<std::uint64_t>(unit + 1));
  std::uniform_real_distribution<double> u01(0, 1);
  std::array<std::uint8_t, st::msg::kMaxDatagramBytes> buf{};
  std::array<st::msg::CanFdFrame, st::msg::kCanFdMaxFramesPerMessage> frames{};
  std::uint32_t datagram_seq = 0;
  if (start_at_realtime_ms > 0) {
    timespec ts{static_cast<time_t>(start_at_realtime_ms / 1000),
                static_cast<long>((start_at_realtime_ms % 1000) * 1'000'000)};
    while (clock_nanosleep(CLOCK_REALTIME, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
  }
  if (start_delay_s > 0)
    sleep_until_mono(mono_now() + static_cast<std::int64_t>(start_delay_s * 1e9));

  std::uint64_t sent = 0, dropped = 0, errors = 0;
  const std::int64_t t0 = mono_now();
  for (int k = 0; k < n; ++k) {
    if (rate_factor > 0)
      sleep_until_mono(t0 + static_cast<std::int64_t>(k * period_ns / rate_factor));
    for (const auto& obs : by_exposure[static_cast<std::size_t>(k)]) {
      if (loss > 0 && u01(rng) < loss) {
        ++dropped;
        ++datagram_seq;
        continue;
      }
      if (can_if.empty()) {
        const int len = st::msg::encode_datagram(obs, buf, datagram_seq++);
        if (len < 0 || sendto(fd, buf.data(), static_cast<std::size_t>(len), 0,
                              reinterpret_cast<sockaddr*>(&dst), sizeof dst) != len) {
          ++errors;
          continue;
        }
      } else {
        const int count = st::msg::encode_canfd(obs, frames);
        bool ok = count > 0;
        for (int f = 0; ok && f < count; ++f) {
          const canfd_frame raw = st::msg::to_linux(frames[static_cast<std::size_t>(f)]);
          // A virtual CAN queue can fill: retry briefly rather than lose the transfer.
          int tries = 0;
          while (write(fd, &raw, sizeof raw) != static_cast<ssize_t>(sizeof raw)) {
            if (errno != ENOBUFS || ++tries > 100) {
              ok = false;
              break;
            }
            usleep(100);
          }
        }
        if (!ok) {
          ++errors;
          continue;
        }
      }
      ++sent;
    }
  }
  close(fd);
  if (!quiet)
    std::fprintf(stderr,
                 "storetrack-sim-units: unit %d: %d exposures, %llu messages sent, %llu "
                 "dropped (injected), %llu send errors\n",
                 unit, n, static_cast<unsigned long long>(sent),
                 static_cast<unsigned long long>(dropped), static_cast<unsigned long long>(errors));
  return errors > 0 ? 1 : 0;
}
