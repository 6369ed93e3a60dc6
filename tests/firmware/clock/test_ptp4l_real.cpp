// The clock monitor against a real ptp4l (linuxptp): a master and a slave ptp4l in two network
// namespaces over a veth pair, software time stamping, both `free_running 1`, so that nothing
// here ever adjusts the machine's clock. Truth by construction: both ptp4l time-stamp with the
// same CLOCK_REALTIME, so the true offset of the slave from the master is 0 (what ptp4l measures
// is its time-stamping noise), and the master's clockIdentity is the EUI-64 of the MAC we give
// its veth end.
//
// What "locked" can mean here: with free_running ptp4l's servo never locks, so its port stays
// UNCALIBRATED (never SLAVE). The strict monitor must therefore say LOCKING and never LOCKED;
// the measure-only monitor (ptp4l.measure_only: lock on the measured offset) locks within the
// test's threshold, 500 us, generous for software time stamps on a loaded 2-core machine.
// Then the master is killed: measure-only goes HOLDOVER then, after the holdover time (3 s
// here), FREE_RUNNING; strict goes straight to FREE_RUNNING (it was never LOCKED). Then the
// slave is killed: ptp4l unreachable, counted, still FREE_RUNNING.
//
// Needs root (network namespaces) and ptp4l; otherwise exits 77 (skipped) with the reason.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "storetrack/clock/clock_monitor.hpp"

namespace storetrack::clock {
namespace {

using Clock = std::chrono::steady_clock;
using time::ClockState;

int run(const std::string& command) {
  return std::system((command + " >/dev/null 2>&1").c_str());
}

std::string unique_tag() {
  return std::to_string(::getpid());
}

/// Namespaces of earlier runs that were killed before cleaning up (ctest's timeout is SIGKILL).
void remove_stale_namespaces() {
  std::FILE* p = ::popen("ip netns list 2>/dev/null", "r");
  if (p == nullptr) return;
  char line[256];
  while (std::fgets(line, sizeof line, p) != nullptr) {
    std::string name(line);
    name = name.substr(0, name.find_first_of(" \n"));
    if (name.rfind("stclk", 0) != 0) continue;
    const std::string pid = name.substr(6);  // stclkm-<pid> / stclks-<pid>
    if (!pid.empty() && ::kill(std::atoi(pid.c_str()), 0) != 0) run("ip netns del " + name);
  }
  ::pclose(p);
}

/// A ptp4l master and slave over a veth pair; everything it made is removed on destruction.
class Ptp4lPair {
 public:
  Ptp4lPair() : tag_(unique_tag()) {
    char dir_template[] = "/tmp/storetrack-ptp4l-XXXXXX";
    if (::mkdtemp(dir_template) != nullptr) dir_ = dir_template;
    ns_master_ = "stclkm-" + tag_;
    ns_slave_ = "stclks-" + tag_;
    veth_master_ = "stm" + tag_;
    veth_slave_ = "sts" + tag_;
  }
  ~Ptp4lPair() {
    stop(master_pid_);
    stop(slave_pid_);
    run("ip netns del " + ns_master_);
    run("ip netns del " + ns_slave_);
    if (!dir_.empty() && !::testing::Test::HasFailure()) std::filesystem::remove_all(dir_);
  }
  Ptp4lPair(const Ptp4lPair&) = delete;
  Ptp4lPair& operator=(const Ptp4lPair&) = delete;

  /// Namespaces, veth pair (master MAC 02:00:00:00:00:01), ptp4l configurations. "" or why not.
  std::string make_network() {
    if (dir_.empty()) return "mkdtemp failed";
    const std::string cmds[] = {
        "ip netns add " + ns_master_,
        "ip netns add " + ns_slave_,
        "ip link add " + veth_master_ + " address 02:00:00:00:00:01 type veth peer name " +
            veth_slave_ + " address 02:00:00:00:00:02",
        "ip link set " + veth_master_ + " netns " + ns_master_,
        "ip link set " + veth_slave_ + " netns " + ns_slave_,
        "ip -n " + ns_master_ + " addr add 10.231.0.1/24 dev " + veth_master_,
        "ip -n " + ns_slave_ + " addr add 10.231.0.2/24 dev " + veth_slave_,
        "ip -n " + ns_master_ + " link set " + veth_master_ + " up",
        "ip -n " + ns_slave_ + " link set " + veth_slave_ + " up",
    };
    for (const std::string& c : cmds)
      if (run(c) != 0) return "'" + c + "' failed";
    const std::string master_uds_path = master_uds();
    const std::string slave_uds_path = slave_uds();
    write_config("master.cfg", "priority1 10\nuds_address " + master_uds_path + "\n");
    write_config("slave.cfg", "slaveOnly 1\nuds_address " + slave_uds_path + "\n");
    return "";
  }

  bool start_master() { return spawn(ns_master_, "master", veth_master_, master_pid_); }
  bool start_slave() { return spawn(ns_slave_, "slave", veth_slave_, slave_pid_); }
  void kill_master() { stop(master_pid_); }
  void kill_slave() { stop(slave_pid_); }

  std::string slave_uds() const { return dir_ + "/slave.uds"; }
  std::string master_uds() const { return dir_ + "/master.uds"; }
  const std::string& dir() const { return dir_; }
  std::string log(const char* role) const {
    std::ifstream in(dir_ + "/" + role + ".log");
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
  }

 private:
  void write_config(const char* name, const std::string& role_lines) {
    // Announce every 250 ms and time out after 2 missed (0.5 s); Sync and Delay_Req 8 per s.
    std::ofstream(dir_ + "/" + name) << "[global]\n"
                                     << "free_running 1\n"
                                     << "time_stamping software\n"
                                     << "logAnnounceInterval -2\n"
                                     << "announceReceiptTimeout 2\n"
                                     << "logSyncInterval -3\n"
                                     << "logMinDelayReqInterval -3\n"
                                     << role_lines;
  }

  bool spawn(const std::string& ns, const char* role, const std::string& veth, pid_t& pid) {
    const std::string config = dir_ + "/" + role + ".cfg";
    const std::string log = dir_ + "/" + role + ".log";
    pid = ::fork();
    if (pid < 0) return false;
    if (pid == 0) {
      std::freopen(log.c_str(), "w", stdout);
      ::dup2(::fileno(stdout), 2);
      // `ip netns exec` enters the namespace and execs ptp4l: the pid stays ptp4l's.
      ::execlp("ip", "ip", "netns", "exec", ns.c_str(), STORETRACK_PTP4L, "-f", config.c_str(),
               "-i", veth.c_str(), "-m", static_cast<char*>(nullptr));
      std::_Exit(127);
    }
    return true;
  }

  static void stop(pid_t& pid) {
    if (pid <= 0) return;
    ::kill(pid, SIGKILL);  // as a crash or power loss would: no goodbye on the network
    ::waitpid(pid, nullptr, 0);
    pid = -1;
  }

  std::string tag_, dir_, ns_master_, ns_slave_, veth_master_, veth_slave_;
  pid_t master_pid_ = -1, slave_pid_ = -1;
};

ClockMonitorConfig monitor_config(const Ptp4lPair& pair, bool measure_only) {
  ClockMonitorConfig c;
  c.ptp4l.uds_path = pair.slave_uds();
  c.ptp4l.client_dir = pair.dir();
  c.ptp4l.reply_timeout_ms = 50;
  c.poll_period_ms = 250;
  c.lock.lock_threshold_ns = 500'000;
  c.lock.lock_polls = 3;
  c.lock.holdover_ns = 3'000'000'000;
  c.lock.measure_only = measure_only;
  return c;
}

double seconds(Clock::duration d) {
  return std::chrono::duration<double>(d).count();
}

/// Samples both monitors every 5 ms until `until` holds or `limit` passes; records what the
/// strict one went through.
template <typename Until>
bool watch(const ClockMonitor& measuring, const ClockMonitor& strict, Clock::duration limit,
           std::vector<ClockState>& strict_seen, Until until) {
  const auto end = Clock::now() + limit;
  while (Clock::now() < end) {
    if (strict_seen.empty() || strict_seen.back() != strict.state())
      strict_seen.push_back(strict.state());
    if (until(measuring.state())) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return false;
}

TEST(Ptp4lReal, LockThenHoldoverThenFreeRunningWhenTheMasterDies) {
  Ptp4lPair pair;
  const std::string why = pair.make_network();
  ASSERT_EQ(why, "");
  ClockMonitor measuring(monitor_config(pair, true));
  ClockMonitor strict(monitor_config(pair, false));
  ASSERT_EQ(measuring.start(), 0) << measuring.error();
  ASSERT_EQ(strict.start(), 0) << strict.error();
  EXPECT_EQ(measuring.state(), ClockState::kFreeRunning);  // no ptp4l yet

  const auto t_start = Clock::now();
  ASSERT_TRUE(pair.start_master());
  ASSERT_TRUE(pair.start_slave());
  std::vector<ClockState> strict_seen;
  ASSERT_TRUE(watch(measuring, strict, std::chrono::seconds(15), strict_seen,
                    [](ClockState s) { return s == ClockState::kLocked; }))
      << "never LOCKED; slave log:\n"
      << pair.log("slave");
  const double to_locked_s = seconds(Clock::now() - t_start);
  // Hold the lock for a second: every poll in it must agree.
  ASSERT_FALSE(watch(measuring, strict, std::chrono::seconds(1), strict_seen, [](ClockState s) {
    return s != ClockState::kLocked;
  })) << "lost LOCKED with the master alive";
  const ClockMonitorStats locked = measuring.stats();
  EXPECT_EQ(locked.port_state, PortState::kUncalibrated);  // free_running: servo never locks
  EXPECT_TRUE(locked.gm_present);
  const std::array<std::uint8_t, 8> master_eui64{0x02, 0x00, 0x00, 0xff, 0xfe, 0x00, 0x00, 0x01};
  EXPECT_EQ(locked.gm_identity, master_eui64);
  const std::int32_t offset_ns = measuring.offset_ns();
  EXPECT_NE(offset_ns, kOffsetUnknown);
  EXPECT_LE(std::abs(offset_ns), 500'000) << "true offset is 0: same CLOCK_REALTIME";
  EXPECT_EQ(strict.state(), ClockState::kLocking);
  EXPECT_NE(strict.offset_ns(), kOffsetUnknown);  // tracking: the offset is reported
  EXPECT_EQ(locked.client.malformed + locked.client.error_status, 0u);

  pair.kill_master();
  const auto t_kill = Clock::now();
  ASSERT_TRUE(watch(measuring, strict, std::chrono::seconds(5), strict_seen,
                    [](ClockState s) { return s != ClockState::kLocked; }));
  const double to_holdover_s = seconds(Clock::now() - t_kill);
  EXPECT_EQ(measuring.state(), ClockState::kHoldover);
  EXPECT_EQ(measuring.offset_ns(), kOffsetUnknown);
  // ptp4l notices after 2 missed announces (0.5 .. 0.75 s), the monitor at its next poll.
  EXPECT_LT(to_holdover_s, 2.0);
  const auto t_holdover = Clock::now();
  ASSERT_TRUE(watch(measuring, strict, std::chrono::seconds(6), strict_seen,
                    [](ClockState s) { return s != ClockState::kHoldover; }));
  const double holdover_s = seconds(Clock::now() - t_holdover);
  EXPECT_EQ(measuring.state(), ClockState::kFreeRunning);
  EXPECT_GE(holdover_s, 2.9);  // 3 s from the poll that saw the loss
  EXPECT_LE(holdover_s, 3.6);  // + at most one poll period and the sampling
  EXPECT_EQ(measuring.stats().port_state, PortState::kListening);
  // strict: LOCKING while the master lived, then FREE_RUNNING, never LOCKED or HOLDOVER.
  ASSERT_FALSE(strict_seen.empty());
  EXPECT_EQ(strict_seen.back(), ClockState::kFreeRunning);
  for (ClockState s : strict_seen)
    EXPECT_TRUE(s == ClockState::kLocking || s == ClockState::kFreeRunning) << static_cast<int>(s);

  pair.kill_slave();
  const std::uint64_t errors_before =
      measuring.stats().client.send_errors + measuring.stats().client.timeouts;
  std::this_thread::sleep_for(std::chrono::milliseconds(800));
  const ClockMonitorStats dead = measuring.stats();
  EXPECT_GT(dead.client.send_errors + dead.client.timeouts, errors_before);
  EXPECT_EQ(measuring.state(), ClockState::kFreeRunning);
  std::printf(
      "measured: LOCKED %.2f s after ptp4l start (offset %d ns); master killed -> HOLDOVER "
      "%.2f s; HOLDOVER -> FREE_RUNNING %.2f s (holdover 3 s, polls every 250 ms)\n",
      to_locked_s, offset_ns, to_holdover_s, holdover_s);
  measuring.stop();
  strict.stop();
}

/// ptp4l's own answer through linuxptp's pmc (GET TIME_STATUS_NP): master_offset and the
/// ingress_time of its Sync. A free_running ptp4l logs no "master offset" lines (not even at
/// logging_level 7: its servo never runs), so pmc is the independent reader of the same figure.
struct PmcStatus {
  bool ok = false;
  std::int64_t master_offset_ns = 0, ingress_time_ns = 0;
};

PmcStatus pmc_time_status(const std::string& uds) {
  const std::string pmc = std::filesystem::path(STORETRACK_PTP4L).parent_path().string() + "/pmc";
  PmcStatus out;
  std::FILE* p =
      ::popen((pmc + " -u -b 0 -s " + uds + " 'GET TIME_STATUS_NP' 2>/dev/null").c_str(), "r");
  if (p == nullptr) return out;
  char line[256];
  bool offset = false, ingress = false;
  while (std::fgets(line, sizeof line, p) != nullptr) {
    std::istringstream fields(line);
    std::string key;
    fields >> key;
    if (key == "master_offset") offset = static_cast<bool>(fields >> out.master_offset_ns);
    if (key == "ingress_time") ingress = static_cast<bool>(fields >> out.ingress_time_ns);
  }
  ::pclose(p);
  out.ok = offset && ingress;
  return out;
}

// The time uncertainty the unit states (clock_uncertainty.hpp) against what ptp4l reports: each
// offset the monitor took into its window is the one linuxptp's pmc reads for the same Sync
// (same ingress_time; pmc asks right after the poll, a new Sync every 125 ms may come between),
// and the figure is their RMS (computed here); after the master dies the figure grows from the
// last measurement as sqrt(u^2 + (y t)^2) and no longer holds. The monitor is polled by the test
// (start(false)), so that the test knows each poll's offset.
TEST(Ptp4lReal, StatedTimeUncertaintyIsTheRmsOfLoggedOffsetsAndGrowsInHoldover) {
  Ptp4lPair pair;
  ASSERT_EQ(pair.make_network(), "");
  ClockMonitorConfig config = monitor_config(pair, true);
  config.uncertainty.offset_window = 8;
  config.uncertainty.holdover_drift_ppb = 1000;
  ClockMonitor monitor(config);
  ASSERT_EQ(monitor.start(false), 0) << monitor.error();
  ASSERT_TRUE(pair.start_master());
  ASSERT_TRUE(pair.start_slave());
  std::vector<std::int64_t> taken;  // each poll's offset that entered the window
  int same_sync = 0, other_sync = 0;
  const auto poll = [&] {
    const std::uint64_t before = monitor.stats().new_offsets;
    monitor.poll_once();
    const ClockMonitorStats s = monitor.stats();
    if (s.new_offsets != before) {
      taken.push_back(s.master_offset_ns);
      const PmcStatus pmc = pmc_time_status(pair.slave_uds());
      if (pmc.ok && pmc.ingress_time_ns == s.ingress_time_ns) {
        EXPECT_EQ(pmc.master_offset_ns, s.master_offset_ns) << "same Sync, another offset";
        ++same_sync;
      } else {
        ++other_sync;  // a newer Sync came between, or the master is gone
      }
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(250));
  };
  const auto rms_of_last = [&](std::size_t n) {
    double sum = 0;
    for (auto it = taken.end() - static_cast<std::ptrdiff_t>(n); it != taken.end(); ++it)
      sum += static_cast<double>(*it) * static_cast<double>(*it);
    return std::sqrt(sum / static_cast<double>(n));
  };
  const auto end = Clock::now() + std::chrono::seconds(20);
  while (Clock::now() < end && !(monitor.state() == ClockState::kLocked && taken.size() >= 12))
    poll();
  ASSERT_EQ(monitor.state(), ClockState::kLocked) << pair.log("slave");
  ASSERT_GE(taken.size(), 12u);
  EXPECT_GE(same_sync, 6) << other_sync << " polls met a newer Sync in pmc";
  const double rms_ns = rms_of_last(8);
  const ClockFigure held = monitor.figure();
  EXPECT_TRUE(held.holding);
  EXPECT_NEAR(held.rms_ns, rms_ns, 1e-9 * rms_ns + 1e-9);
  EXPECT_EQ(held.sigma_ns_at(time::monotonic_now_ns() + 5 * 1'000'000'000LL, 1000), held.rms_ns);

  pair.kill_master();
  const auto limit = Clock::now() + std::chrono::seconds(5);
  while (Clock::now() < limit && monitor.state() != ClockState::kHoldover)
    poll();  // the master's last Syncs until ptp4l notices are still measurements
  ASSERT_EQ(monitor.state(), ClockState::kHoldover);
  const ClockFigure lost = monitor.figure();
  EXPECT_FALSE(lost.holding);
  EXPECT_NEAR(lost.rms_ns, rms_of_last(8), 1e-9 * lost.rms_ns + 1e-9);
  const time::MonotonicNs t1 = time::monotonic_now_ns();
  const double u1 = lost.sigma_ns_at(t1, 1000);
  const double u2 = lost.sigma_ns_at(t1 + 2'000'000'000, 1000);
  const double age_s = static_cast<double>(t1 - lost.measured_at_ns) * 1e-9;
  EXPECT_GT(age_s, 0.0);
  EXPECT_LT(age_s, 3.0);  // the master died at most ~1.5 s (detection) + a poll ago
  EXPECT_NEAR(u1, std::hypot(lost.rms_ns, 1000 * age_s), 1e-6 * u1);
  EXPECT_NEAR(u2, std::hypot(lost.rms_ns, 1000 * (age_s + 2)), 1e-6 * u2);
  EXPECT_GT(u2, u1 + 1500);  // 1 ppm over 2 s: 2000 ns in quadrature, most of it visible
  std::printf(
      "stated time uncertainty: %zu offsets taken, %d checked against pmc on the same Sync (%d "
      "met a newer one); RMS of the last 8 = %.0f ns; master killed -> HOLDOVER, %.2f s after "
      "the last measurement u = %.0f ns, 2 s later %.0f ns\n",
      taken.size(), same_sync, other_sync, rms_ns, age_s, u1, u2);
  monitor.stop();
}

/// Why this test cannot run here, or "".
std::string cannot_run() {
  if (std::string(STORETRACK_PTP4L).empty() || ::access(STORETRACK_PTP4L, X_OK) != 0)
    return "ptp4l not installed (apt-get install linuxptp)";
  if (::geteuid() != 0) return "needs root for network namespaces";
  std::string probe = "stclkp-";  // not literal + string&& (GCC 12 aarch64 -Warray-bounds)
  probe += unique_tag();
  if (run("ip netns add " + probe) != 0) return "cannot create a network namespace";
  run("ip netns del " + probe);
  return "";
}

}  // namespace
}  // namespace storetrack::clock

int main(int argc, char** argv) {
  const std::string why = storetrack::clock::cannot_run();
  if (!why.empty()) {
    std::printf("SKIP: %s\n", why.c_str());
    return 77;
  }
  storetrack::clock::remove_stale_namespaces();
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
