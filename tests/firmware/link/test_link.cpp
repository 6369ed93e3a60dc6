// UDP link end-to-end on loopback, decoded by the ICD codec; CAN error-frame classification;
// CAN open errors are clear (this machine's kernel has no CAN: the real path runs in the VM rig).
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <linux/can.h>
#include <linux/can/error.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdint>
#include <variant>

#include "storetrack/link/canfd_link.hpp"
#include "storetrack/link/udp_link.hpp"
#include "storetrack/msg/udp_codec.hpp"

namespace storetrack::link {
namespace {

// UdpLinkConfig has a member without a default initializer: brace-initialising only the
// destination trips -Wmissing-field-initializers (-Werror).
UdpLinkConfig udp_config(std::string destination) {
  UdpLinkConfig c;
  c.destination = std::move(destination);
  return c;
}

struct Receiver {
  int fd = -1;
  int port = 0;
  Receiver() {
    fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
    socklen_t len = sizeof a;
    getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
    port = ntohs(a.sin_port);
  }
  ~Receiver() { close(fd); }
  int receive(std::uint8_t* buf, std::size_t size, int timeout_ms = 1000) {
    pollfd p{fd, POLLIN, 0};
    if (poll(&p, 1, timeout_ms) != 1) return -ETIMEDOUT;
    return static_cast<int>(recv(fd, buf, size, 0));
  }
};

msg::MarkObservations make_observations(int marks) {
  msg::MarkObservations m{};
  m.unit_id = 3;
  m.camera_id = 7;
  m.trigger_seq = 123456;
  m.exposure_start_tai_ns = 1'700'000'000'123'456'789LL;
  m.exposure_start_mono_ns = 987'654'321;
  m.exposure_duration_ns = 500'000;
  m.clock_state = 2;
  m.flags = msg::exposure_flags::kTriggerMissing;
  m.mark_count = static_cast<std::uint8_t>(marks);
  for (int i = 0; i < marks; ++i) {
    auto& o = m.marks[static_cast<std::size_t>(i)];
    o.x_px = 10.0f + 29.37f * static_cast<float>(i);
    o.y_px = 1000.0f - 13.11f * static_cast<float>(i);
    o.sigma_px = 0.02f;
    o.peak = static_cast<std::uint16_t>(100 + i);
    o.diameter_px = 6.5f;
    o.flags = msg::mark_flags::kBorder;
  }
  return m;
}

TEST(UdpLink, ObservationsArriveOnLoopbackAndDecode) {
  Receiver rx;
  UdpLinkConfig cfg;
  cfg.destination = "127.0.0.1:" + std::to_string(rx.port);
  UdpLink link(cfg);
  ASSERT_EQ(link.open(), 0) << link.error();
  for (int marks : {0, 1, 16, 64}) {
    const auto sent = make_observations(marks);
    ASSERT_EQ(link.send(sent), 0);
    std::uint8_t buf[2048];
    const int n = rx.receive(buf, sizeof buf);
    ASSERT_GT(n, 0);
    msg::AnyMessage any;
    msg::DatagramHeader header;
    ASSERT_EQ(msg::decode_datagram(std::span<const std::uint8_t>(buf, static_cast<std::size_t>(n)),
                                   any, &header),
              msg::DecodeError::kNone);
    ASSERT_TRUE(std::holds_alternative<msg::MarkObservations>(any));
    const auto& got = std::get<msg::MarkObservations>(any);
    EXPECT_EQ(got.unit_id, sent.unit_id);
    EXPECT_EQ(got.camera_id, sent.camera_id);
    EXPECT_EQ(got.trigger_seq, sent.trigger_seq);
    EXPECT_EQ(got.exposure_start_tai_ns, sent.exposure_start_tai_ns);
    EXPECT_EQ(got.flags, sent.flags);
    ASSERT_EQ(got.mark_count, sent.mark_count);
    for (int i = 0; i < marks; ++i) {
      const auto& a = got.marks[static_cast<std::size_t>(i)];
      const auto& b = sent.marks[static_cast<std::size_t>(i)];
      EXPECT_NEAR(a.x_px, b.x_px, 1.0 / 512);  // 1/256 px quantisation
      EXPECT_NEAR(a.y_px, b.y_px, 1.0 / 512);
      EXPECT_NEAR(a.sigma_px, b.sigma_px, 0.03 * b.sigma_px);  // 4.4 % log steps
      EXPECT_EQ(a.flags, b.flags);
    }
  }
  msg::UnitHealth h{};
  h.unit_id = 3;
  h.clock_state = 0;
  h.frames_captured = 42;
  h.status = msg::unit_status::kCapturing;
  ASSERT_EQ(link.send(h), 0);
  std::uint8_t buf[2048];
  const int n = rx.receive(buf, sizeof buf);
  ASSERT_GT(n, 0);
  msg::AnyMessage any;
  ASSERT_EQ(
      msg::decode_datagram(std::span<const std::uint8_t>(buf, static_cast<std::size_t>(n)), any),
      msg::DecodeError::kNone);
  ASSERT_TRUE(std::holds_alternative<msg::UnitHealth>(any));
  EXPECT_EQ(std::get<msg::UnitHealth>(any).frames_captured, 42u);
  const LinkStats s = link.stats();
  EXPECT_EQ(s.observations_sent, 4u);
  EXPECT_EQ(s.health_sent, 1u);
  EXPECT_EQ(s.tx_errors, 0u);
}

TEST(UdpLink, UnencodableMessageIsCountedNotSent) {
  Receiver rx;
  UdpLink link(udp_config("127.0.0.1:" + std::to_string(rx.port)));
  ASSERT_EQ(link.open(), 0);
  auto m = make_observations(1);
  m.marks[0].x_px = NAN;
  EXPECT_EQ(link.send(m), -ERANGE);
  EXPECT_EQ(link.stats().encode_errors, 1u);
  std::uint8_t buf[64];
  EXPECT_EQ(rx.receive(buf, sizeof buf, 50), -ETIMEDOUT);
}

TEST(UdpLink, BadDestinationIsAClearError) {
  UdpLink link(udp_config("localhost"));
  EXPECT_EQ(link.open(), -EINVAL);
  EXPECT_NE(std::string(link.error()).find("localhost"), std::string::npos);
  sockaddr_in a{};
  EXPECT_EQ(parse_ipv4_endpoint("239.1.2.3:5000", a), 0);
  EXPECT_EQ(ntohs(a.sin_port), 5000);
  EXPECT_EQ(parse_ipv4_endpoint("1.2.3.4:99999", a), -EINVAL);
  EXPECT_EQ(parse_ipv4_endpoint("1.2.3.4:", a), -EINVAL);
}

TEST(UdpLink, MulticastSocketOpens) {
  UdpLink link(udp_config("239.255.42.1:50001"));
  EXPECT_EQ(link.open(), 0) << link.error();
}

TEST(CanFdLink, ErrorFrameClassification) {
  std::uint8_t data[8] = {};
  auto e = classify_error_frame(CAN_ERR_FLAG | CAN_ERR_BUSOFF, data, 8);
  EXPECT_TRUE(e.bus_off);
  EXPECT_FALSE(e.restarted);
  e = classify_error_frame(CAN_ERR_FLAG | CAN_ERR_RESTARTED, data, 8);
  EXPECT_TRUE(e.restarted);
  data[1] = CAN_ERR_CRTL_ACTIVE;
  e = classify_error_frame(CAN_ERR_FLAG | CAN_ERR_CRTL, data, 8);
  EXPECT_TRUE(e.controller_problem);
  EXPECT_TRUE(e.restarted);
  data[1] = CAN_ERR_CRTL_TX_PASSIVE;
  e = classify_error_frame(CAN_ERR_FLAG | CAN_ERR_CRTL | CAN_ERR_ACK, data, 8);
  EXPECT_FALSE(e.restarted);
  EXPECT_TRUE(e.no_ack);
  e = classify_error_frame(0x123, data, 8);  // not an error frame
  EXPECT_FALSE(e.bus_off || e.restarted || e.controller_problem);
}

TEST(CanFdLink, OpenFailureNamesTheInterface) {
  CanFdLinkConfig cfg;
  cfg.interface = "nosuchcan9";
  CanFdLink link(cfg);
  const int rc = link.open();
  ASSERT_LT(rc, 0);  // no CAN in this kernel, or no such interface
  EXPECT_NE(std::string(link.error()).find("nosuchcan9"), std::string::npos) << link.error();
  EXPECT_EQ(link.send(make_observations(1)), -ENOTCONN);
}

}  // namespace
}  // namespace storetrack::link
