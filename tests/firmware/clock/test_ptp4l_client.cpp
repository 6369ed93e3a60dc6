// The UNIX-socket transport and the monitor against a fake ptp4l: a datagram server thread in
// the test that answers GETs with ptp4l's own captured replies (ptp4l_captures.hpp, sequenceId
// patched to the request's), or stays silent, answers late, or answers with garbage first.
#include <gtest/gtest.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include "fake_ptp4l.hpp"
#include "ptp4l_captures.hpp"
#include "storetrack/clock/clock_monitor.hpp"
#include "storetrack/clock/ptp4l_client.hpp"

namespace storetrack::clock {
namespace {

using test::Datagram;
using test::FakePtp4l;
using test::ptp4l_answers;
using test::with_sequence;

class Ptp4lClientTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char dir_template[] = "/tmp/storetrack-clock-XXXXXX";
    ASSERT_NE(::mkdtemp(dir_template), nullptr);
    dir_ = dir_template;
    config_.uds_path = dir_ + "/ptp4l";
    config_.client_dir = dir_;
    config_.reply_timeout_ms = 100;
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::string dir_;
  Ptp4lClientConfig config_;
};

TEST_F(Ptp4lClientTest, ReadsTheThreeDataSets) {
  FakePtp4l server(config_.uds_path, ptp4l_answers);
  Ptp4lClient client(config_);
  ASSERT_EQ(client.open(), 0) << client.error();
  ManagementReply reply;
  ASSERT_EQ(client.get(ManagementId::kPortDataSet, reply), 0);
  PortDataSet port;
  ASSERT_TRUE(parse_port_data_set(reply.data, port));
  EXPECT_EQ(port.port_state, PortState::kUncalibrated);
  ASSERT_EQ(client.get(ManagementId::kTimeStatusNp, reply), 0);
  TimeStatusNp status;
  ASSERT_TRUE(parse_time_status_np(reply.data, status));
  EXPECT_EQ(status.master_offset_ns, 616);
  ASSERT_EQ(client.get(ManagementId::kTimePropertiesDataSet, reply), 0);
  const Ptp4lClientStats s = client.stats();
  EXPECT_EQ(s.requests, 3u);
  EXPECT_EQ(s.replies, 3u);
  EXPECT_EQ(s.timeouts + s.malformed + s.stale + s.send_errors, 0u);
}

TEST_F(Ptp4lClientTest, NoPtp4lIsASendErrorNotAHang) {
  Ptp4lClient client(config_);
  ASSERT_EQ(client.open(), 0);
  ManagementReply reply;
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(client.get(ManagementId::kPortDataSet, reply), -ENOENT);
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::milliseconds(50));
  EXPECT_EQ(client.stats().send_errors, 1u);
  EXPECT_EQ(client.stats().last_errno, ENOENT);
}

TEST_F(Ptp4lClientTest, SilentPtp4lTimesOutAfterTheReplyTimeout) {
  FakePtp4l server(config_.uds_path, [](const Datagram&) { return std::vector<Datagram>{}; });
  Ptp4lClient client(config_);
  ASSERT_EQ(client.open(), 0);
  ManagementReply reply;
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(client.get(ManagementId::kTimeStatusNp, reply), -ETIMEDOUT);
  const auto elapsed = std::chrono::steady_clock::now() - t0;
  EXPECT_GE(elapsed, std::chrono::milliseconds(100));
  EXPECT_LT(elapsed, std::chrono::milliseconds(300));
  EXPECT_EQ(client.stats().timeouts, 1u);
}

TEST_F(Ptp4lClientTest, StaleAndGarbageRepliesAreCountedAndSkipped) {
  FakePtp4l server(config_.uds_path, [](const Datagram& request) {
    std::vector<Datagram> out;
    Datagram stale = ptp4l_answers(request).front();
    stale[31] = static_cast<std::uint8_t>(stale[31] - 1);  // the previous request's answer
    out.push_back(stale);
    out.push_back(Datagram{0x0d, 0x02, 0x00});  // a runt
    Datagram sync = ptp4l_answers(request).front();
    sync[0] = 0x00;  // not a management message
    out.push_back(sync);
    out.push_back(ptp4l_answers(request).front());
    return out;
  });
  Ptp4lClient client(config_);
  ASSERT_EQ(client.open(), 0);
  ManagementReply reply;
  ASSERT_EQ(client.get(ManagementId::kTimeStatusNp, reply), 0);
  TimeStatusNp status;
  ASSERT_TRUE(parse_time_status_np(reply.data, status));
  EXPECT_EQ(status.master_offset_ns, 616);
  const Ptp4lClientStats s = client.stats();
  EXPECT_EQ(s.stale, 1u);
  EXPECT_EQ(s.malformed, 2u);
  EXPECT_EQ(s.replies, 1u);
}

TEST_F(Ptp4lClientTest, ErrorStatusIsEproto) {
  FakePtp4l server(config_.uds_path, [](const Datagram& request) {
    Datagram error = with_sequence(test::from_hex(test::kSlaveErrorNoSuchId), request);
    return std::vector<Datagram>{error};
  });
  Ptp4lClient client(config_);
  ASSERT_EQ(client.open(), 0);
  ManagementReply reply;
  EXPECT_EQ(client.get(ManagementId::kPortDataSet, reply), -EPROTO);
  EXPECT_EQ(reply.error_id, 0x0002);
  EXPECT_EQ(client.stats().error_status, 1u);
}

TEST_F(Ptp4lClientTest, ClientSocketInAMissingDirectoryFailsAtOpen) {
  config_.client_dir = dir_ + "/missing";
  Ptp4lClient client(config_);
  EXPECT_EQ(client.open(), -ENOENT);
  EXPECT_NE(client.error().find("bind"), std::string::npos);
}

TEST_F(Ptp4lClientTest, OpenAndCloseLeaveNoSocketFileBehind) {
  Ptp4lClient client(config_);
  ASSERT_EQ(client.open(), 0);
  EXPECT_TRUE(std::filesystem::exists(client.client_path()));
  client.close();
  EXPECT_FALSE(std::filesystem::exists(client.client_path()));
}

/// Waits up to `limit` for the monitor to reach `want`.
bool wait_for(const ClockMonitor& m, time::ClockState want, std::chrono::milliseconds limit) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < end) {
    if (m.state() == want) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return m.state() == want;
}

TEST_F(Ptp4lClientTest, MonitorThreadPublishesLockLossHoldoverAndFreeRunning) {
  FakePtp4l server(config_.uds_path, ptp4l_answers);
  ClockMonitorConfig mc;
  mc.ptp4l = config_;
  mc.ptp4l.reply_timeout_ms = 20;
  mc.poll_period_ms = 50;
  mc.lock.lock_threshold_ns = 1000;
  mc.lock.lock_polls = 3;
  mc.lock.measure_only = true;  // the captures are of a free_running (UNCALIBRATED) slave
  mc.lock.holdover_ns = 400'000'000;
  ClockMonitor monitor(mc);
  EXPECT_EQ(monitor.state(), time::ClockState::kFreeRunning);
  EXPECT_EQ(monitor.offset_ns(), kOffsetUnknown);
  ASSERT_EQ(monitor.start(), 0) << monitor.error();
  ASSERT_TRUE(wait_for(monitor, time::ClockState::kLocked, std::chrono::seconds(2)));
  EXPECT_EQ(monitor.offset_ns(), 616);
  EXPECT_GE(monitor.stats().polls, 3u);
  // ptp4l stops answering: holdover, then free-running once the holdover time is over.
  server.set_responder([](const Datagram&) { return std::vector<Datagram>{}; });
  const auto t_silent = std::chrono::steady_clock::now();
  ASSERT_TRUE(wait_for(monitor, time::ClockState::kHoldover, std::chrono::seconds(1)));
  EXPECT_EQ(monitor.offset_ns(), kOffsetUnknown);
  ASSERT_TRUE(wait_for(monitor, time::ClockState::kFreeRunning, std::chrono::seconds(2)));
  EXPECT_GE(std::chrono::steady_clock::now() - t_silent, std::chrono::milliseconds(400));
  // And back: ptp4l answers again.
  server.set_responder(ptp4l_answers);
  ASSERT_TRUE(wait_for(monitor, time::ClockState::kLocked, std::chrono::seconds(2)));
  monitor.stop();
  const ClockMonitorStats s = monitor.stats();
  EXPECT_GE(s.transitions, 4u);
  EXPECT_GT(s.client.timeouts, 0u);
  const std::array<std::uint8_t, 8> master{0x86, 0x23, 0xd8, 0xff, 0xfe, 0xf0, 0x0d, 0x3a};
  EXPECT_EQ(s.gm_identity, master);
}

}  // namespace
}  // namespace storetrack::clock

namespace storetrack::clock {

// A UNIX socket path has 108 bytes with its NUL (sys/un.h). The client binds
// <client_dir>/storetrack-pmc.<pid>.<n>: "/storetrack-pmc." is 16 bytes, a pid at most 7 digits
// (PID_MAX_LIMIT 4194304), "." 1, an instance number at most 10: client_dir may have 107 - 34 =
// 73 bytes. Refused beyond, naming the path, before any socket is made.
TEST(Ptp4lSocketPaths, ClientDirLimitFollowsTheLongestNameTheClientCanBind) {
  static_assert(sizeof(sockaddr_un{}.sun_path) == 108);
  Ptp4lClientConfig config;
  config.uds_path = "/run/ptp4l";
  config.client_dir = "/" + std::string(72, 'd');  // 73 bytes
  EXPECT_EQ(socket_path_problem(config), "");
  config.client_dir += "e";  // 74 bytes
  const std::string problem = socket_path_problem(config);
  EXPECT_NE(problem.find("ptp4l.client_dir is too long by 1 bytes"), std::string::npos) << problem;
  EXPECT_NE(problem.find(config.client_dir), std::string::npos) << problem;

  Ptp4lClient client(config);
  EXPECT_EQ(client.open(), -ENAMETOOLONG);
}

TEST(Ptp4lSocketPaths, UdsPathOverTheLimitIsNamed) {
  Ptp4lClientConfig config;
  config.client_dir = "/tmp";
  config.uds_path = "/" + std::string(106, 'u');  // 107 bytes: fits
  EXPECT_EQ(socket_path_problem(config), "");
  config.uds_path += "v";
  const std::string problem = socket_path_problem(config);
  EXPECT_NE(problem.find("ptp4l.uds_path is 108 bytes"), std::string::npos) << problem;
  config.uds_path.clear();
  EXPECT_EQ(socket_path_problem(config), "ptp4l.uds_path is empty");
}

}  // namespace storetrack::clock
