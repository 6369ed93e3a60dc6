// Runs INSIDE the rig VM only (tests/rig/guest/canfd_link.sh creates the vcan interface and
// passes its name in STORETRACK_RIG_CAN_IF): the unit's CanFdLink and the host's CanFdReceiver
// against Linux's real SocketCAN stack (vcan, CAN FD, mtu 72). Not a ctest of its own: outside
// the VM there is no CAN in this machine's kernel.
#include <gtest/gtest.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "storetrack/ingest/receivers.hpp"
#include "storetrack/link/canfd_link.hpp"
#include "storetrack/msg/canfd_codec.hpp"
#include "storetrack/time/time.hpp"

namespace msg = storetrack::msg;

namespace {

std::string can_if() {
  const char* name = std::getenv("STORETRACK_RIG_CAN_IF");
  return name != nullptr ? name : "";
}

msg::MarkObservations make_obs(std::uint32_t seq, int marks) {
  msg::MarkObservations m{};
  m.unit_id = 3;
  m.camera_id = 7;
  m.trigger_seq = seq;
  m.exposure_start_tai_ns = 1'800'000'000'000'000'000 + std::int64_t{seq} * 10'000'000;
  m.exposure_start_mono_ns = 5'000'000'000 + std::int64_t{seq} * 10'000'000;
  m.exposure_duration_ns = 500'000;
  m.clock_state = 2;
  m.flags = 0;
  m.mark_count = static_cast<std::uint8_t>(marks);
  for (int i = 0; i < marks; ++i) {
    auto& k = m.marks[static_cast<std::size_t>(i)];
    k.x_px = 10.25f + 29.5f * static_cast<float>(i) + 0.125f * static_cast<float>(seq % 7);
    k.y_px = 1000.5f - 13.75f * static_cast<float>(i);
    k.sigma_px = 0.05f;
    k.peak = static_cast<std::uint16_t>(100 + i);
    k.diameter_px = 6.5f;
    k.flags = static_cast<std::uint8_t>(i % 16);
  }
  return m;
}

// Wire form: two messages are equal at wire precision when they encode to the same frames.
std::vector<msg::CanFdFrame> wire(const msg::MarkObservations& m) {
  std::vector<msg::CanFdFrame> f(msg::kCanFdMaxFragments);
  const int n = msg::encode_canfd(m, f);
  EXPECT_GT(n, 0);
  f.resize(static_cast<std::size_t>(std::max(n, 0)));
  return f;
}

bool same_wire(const std::vector<msg::CanFdFrame>& a, const std::vector<msg::CanFdFrame>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (a[i].can_id != b[i].can_id || a[i].len != b[i].len ||
        std::memcmp(a[i].data, b[i].data, a[i].len) != 0) {
      return false;
    }
  }
  return true;
}

int open_raw(const std::string& ifname) {
  const int fd = socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK, CAN_RAW);
  if (fd < 0) return -errno;
  const int on = 1;
  setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on);
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(if_nametoindex(ifname.c_str()));
  if (bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    const int err = errno;
    close(fd);
    return -err;
  }
  return fd;
}

struct Tap {  // raw frames as seen on the bus (candump's view)
  std::vector<canfd_frame> frames;
  std::vector<int> sizes;
  void drain(int fd) {
    canfd_frame f{};
    for (;;) {
      const ssize_t n = read(fd, &f, sizeof f);
      if (n <= 0) return;
      frames.push_back(f);
      sizes.push_back(static_cast<int>(n));
    }
  }
};

// Receives into `got` until it holds `want` messages or timeout; returns `got`.
std::vector<msg::MarkObservations> receive(storetrack::ingest::CanFdReceiver& rx, std::size_t want,
                                           int timeout_ms,
                                           std::vector<msg::MarkObservations> got = {}) {
  const std::int64_t end =
      storetrack::time::monotonic_now_ns() + std::int64_t{timeout_ms} * 1'000'000;
  for (;;) {  // at least one non-blocking drain, even with timeout 0
    pollfd p{rx.fd(), POLLIN, 0};
    if (poll(&p, 1, timeout_ms > 0 ? 50 : 0) > 0) {
      rx.receive([&](const msg::AnyMessage& m) {
        if (const auto* o = std::get_if<msg::MarkObservations>(&m)) got.push_back(*o);
      });
    }
    if (got.size() >= want || storetrack::time::monotonic_now_ns() >= end) return got;
  }
}

bool valid_fd_len(int len) {
  static const std::set<int> kLens{0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64};
  return kLens.count(len) == 1;
}

class RigCanFd : public ::testing::Test {
 protected:
  void SetUp() override {
    ifname_ = can_if();
    ASSERT_FALSE(ifname_.empty()) << "run by tests/rig/guest/canfd_link.sh inside the VM";
    link_ = std::make_unique<storetrack::link::CanFdLink>(
        storetrack::link::CanFdLinkConfig{.interface = ifname_});
    ASSERT_EQ(link_->open(), 0) << link_->error();
    ASSERT_EQ(rx_.open(ifname_), 0);
    tap_fd_ = open_raw(ifname_);
    ASSERT_GE(tap_fd_, 0);
  }
  void TearDown() override {
    if (tap_fd_ >= 0) close(tap_fd_);
  }
  std::string ifname_;
  std::unique_ptr<storetrack::link::CanFdLink> link_;
  storetrack::ingest::CanFdReceiver rx_;
  int tap_fd_ = -1;
};

}  // namespace

TEST_F(RigCanFd, ObservationsCrossTheRealStackWholeAndWithIcdFraming) {
  std::vector<msg::MarkObservations> sent;
  std::vector<msg::MarkObservations> got;
  Tap tap;
  std::size_t expected_frames = 0;
  for (std::uint32_t seq = 0; seq < 65; ++seq) {
    sent.push_back(make_obs(seq, static_cast<int>(seq)));  // 0..64 marks: 1..9 frames
    expected_frames += msg::canfd_frame_count(sent.back());
    ASSERT_EQ(link_->send(sent.back()), 0) << link_->error();
    link_->service();
    // Pace like a 100 Hz unit and drain as the host does: a burst of 65 x 9 frames would
    // overflow vcan's txqueuelen and the receiving sockets' buffers.
    usleep(2000);
    tap.drain(tap_fd_);
    got = receive(rx_, sent.size(), 0, std::move(got));
  }
  got = receive(rx_, sent.size(), 5000, std::move(got));
  tap.drain(tap_fd_);
  ASSERT_EQ(got.size(), sent.size());
  for (std::size_t i = 0; i < sent.size(); ++i) {
    EXPECT_TRUE(same_wire(wire(got[i]), wire(sent[i]))) << "message " << i;
  }
  // The bus view (what candump prints): 29-bit ids of the ICD, FD frames, valid FD lengths.
  ASSERT_EQ(tap.frames.size(), expected_frames);
  for (std::size_t i = 0; i < tap.frames.size(); ++i) {
    const canfd_frame& f = tap.frames[i];
    EXPECT_EQ(tap.sizes[i], static_cast<int>(CANFD_MTU)) << "not a CAN FD frame";
    ASSERT_TRUE(f.can_id & CAN_EFF_FLAG) << "ICD ids are 29-bit";
    const std::uint32_t id = f.can_id & CAN_EFF_MASK;
    EXPECT_EQ(msg::canid::lcc(id), msg::canid::kLccNoc);
    EXPECT_EQ(msg::canid::fid(id), 0x01);
    EXPECT_EQ(msg::canid::unit(id), 3);
    EXPECT_EQ(msg::canid::camera(id), 7);
    EXPECT_EQ(msg::canid::version(id), msg::kMarkObservationsVersion);
    EXPECT_TRUE(valid_fd_len(f.len)) << int(f.len);
  }
  EXPECT_EQ(rx_.counters().classic_or_bad_frames, 0u);
  EXPECT_EQ(link_->stats().observations_sent, sent.size());
}

TEST_F(RigCanFd, MalformedFramesAreCountedAndDropped) {
  const int inj = open_raw(ifname_);
  ASSERT_GE(inj, 0);
  // 1) classic CAN frame with a standard id
  can_frame classic{};
  classic.can_id = 0x123;
  classic.len = 4;
  ASSERT_EQ(write(inj, &classic, sizeof classic), static_cast<ssize_t>(sizeof classic));
  // 2) one-frame transfer with a corrupted payload byte (CRC-32 must catch it)
  const auto good = wire(make_obs(1000, 0));
  ASSERT_EQ(good.size(), 1u);
  canfd_frame bad{};
  bad.can_id = good[0].can_id | CAN_EFF_FLAG;
  bad.len = good[0].len;
  std::memcpy(bad.data, good[0].data, good[0].len);
  bad.data[5] ^= 0x40;
  ASSERT_EQ(write(inj, &bad, sizeof bad), static_cast<ssize_t>(sizeof bad));
  // 3) a frame on another ARINC 825 channel (not ours)
  bad.can_id = (msg::canid::make(5, 0x01, 3, 7, msg::kMarkObservationsVersion) | CAN_EFF_FLAG);
  std::memcpy(bad.data, good[0].data, good[0].len);
  ASSERT_EQ(write(inj, &bad, sizeof bad), static_cast<ssize_t>(sizeof bad));
  close(inj);
  // then a valid message still gets through
  ASSERT_EQ(link_->send(make_obs(1001, 3)), 0);
  const auto got = receive(rx_, 1, 3000);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].trigger_seq, 1001u);
  const auto& c = rx_.counters();
  const auto& r = rx_.reassembly_counters();
  EXPECT_EQ(c.classic_or_bad_frames, 1u);
  EXPECT_EQ(r.crc_errors, 1u);
  EXPECT_EQ(r.not_ours, 1u);
  EXPECT_EQ(c.decoded, 1u);
}

TEST_F(RigCanFd, InterfaceDownDuringStreamingIsSurvivedAndReported) {
  std::uint32_t seq = 0;
  for (; seq < 10; ++seq) {
    ASSERT_EQ(link_->send(make_obs(seq, 8)), 0);
    usleep(1000);
  }
  ASSERT_EQ(receive(rx_, 10, 3000).size(), 10u);

  ASSERT_EQ(std::system(("ip link set " + ifname_ + " down").c_str()), 0);
  int failed = 0;
  for (int i = 0; i < 10; ++i, ++seq) {
    failed += link_->send(make_obs(seq, 8)) != 0;
    link_->service();
  }
  rx_.receive([](const msg::AnyMessage&) {});  // must not crash on a downed interface
  const auto down = link_->stats();
  EXPECT_EQ(failed, 10) << "sends on a downed interface must fail, not vanish";
  EXPECT_TRUE(down.link_down || down.tx_errors + down.dropped_exposures >= 10u)
      << "link_down=" << down.link_down << " tx_errors=" << down.tx_errors
      << " dropped=" << down.dropped_exposures << " last_errno=" << down.last_errno;

  ASSERT_EQ(std::system(("ip link set " + ifname_ + " up").c_str()), 0);
  // Recovery: the same link and receiver objects carry traffic again.
  std::vector<msg::MarkObservations> got;
  const std::uint32_t first_after = seq;
  for (int i = 0; i < 50 && got.empty(); ++i, ++seq) {
    link_->send(make_obs(seq, 8));
    link_->service();
    for (const auto& m : receive(rx_, 1, 100))
      got.push_back(m);
  }
  ASSERT_FALSE(got.empty()) << "no message after the interface came back up";
  EXPECT_GE(got[0].trigger_seq, first_after);
  EXPECT_FALSE(link_->stats().link_down);
}
