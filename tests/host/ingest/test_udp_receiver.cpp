// UdpReceiver on loopback: real datagrams from the msg codec, plus corrupted and foreign ones,
// which must be counted by decode error and never delivered.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <array>
#include <string>
#include <vector>

#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/ingest/receivers.hpp"
#include "storetrack/msg/crc.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::ingest {
namespace {

class Sender {
 public:
  explicit Sender(std::uint16_t port, const char* from = nullptr) {
    fd_ = socket(AF_INET, SOCK_DGRAM, 0);
    if (from) {  // send from this loopback address (any of 127/8 works on Linux)
      sockaddr_in src{};
      src.sin_family = AF_INET;
      inet_pton(AF_INET, from, &src.sin_addr);
      EXPECT_EQ(bind(fd_, reinterpret_cast<sockaddr*>(&src), sizeof src), 0);
    }
    dst_.sin_family = AF_INET;
    dst_.sin_port = htons(port);
    inet_pton(AF_INET, "127.0.0.1", &dst_.sin_addr);
  }
  ~Sender() { close(fd_); }
  void send(std::span<const std::uint8_t> bytes) {
    ASSERT_EQ(
        sendto(fd_, bytes.data(), bytes.size(), 0, reinterpret_cast<sockaddr*>(&dst_), sizeof dst_),
        static_cast<ssize_t>(bytes.size()));
  }

 private:
  int fd_;
  sockaddr_in dst_{};
};

msg::MarkObservations observation(std::uint32_t seq) {
  msg::MarkObservations o{};
  o.unit_id = 1;
  o.camera_id = 3;
  o.trigger_seq = seq;
  o.exposure_start_tai_ns = 1'800'000'000'000'000'000 + seq * 2'500'000LL;
  o.exposure_start_mono_ns = 1000 + seq;
  o.exposure_duration_ns = 400'000;
  o.clock_state = 2;
  o.mark_count = 2;
  o.marks[0] = {100.25f, 200.5f, 0.05f, 120, 6.0f, 0};
  o.marks[1] = {1500.0f, 900.75f, 0.08f, 200, 7.5f, 1};
  return o;
}

void drain(UdpReceiver& rx, std::vector<msg::MarkObservations>& got, int expected_datagrams) {
  for (int spins = 0;
       spins < 200 && rx.counters().datagrams < static_cast<std::uint64_t>(expected_datagrams);
       ++spins) {
    pollfd p{rx.fd(), POLLIN, 0};
    poll(&p, 1, 10);
    rx.receive([&](const msg::AnyMessage& m) {
      if (auto* o = std::get_if<msg::MarkObservations>(&m)) got.push_back(*o);
    });
  }
}

TEST(UdpReceiver, DeliversValidDatagramsAndCountsBadOnes) {
  UdpReceiver rx;
  ASSERT_EQ(rx.open("127.0.0.1", 0), 0);
  Sender tx(rx.port());
  std::array<std::uint8_t, msg::kMaxDatagramBytes> buf{};
  int sent = 0;
  for (std::uint32_t k = 0; k < 20; ++k) {
    if (k == 5) continue;  // one datagram "lost": the sender's counter skips it
    const int n = msg::encode_datagram(observation(k), buf, k);
    ASSERT_GT(n, 0);
    tx.send(std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(n)));
    ++sent;
  }
  int n = msg::encode_datagram(observation(99), buf, 20);
  buf[static_cast<std::size_t>(n) / 2] ^= 0x40;  // bit flip: CRC error
  tx.send(std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(n)));
  const std::uint8_t junk[] = {1, 2, 3};
  tx.send(junk);
  std::vector<msg::MarkObservations> got;
  drain(rx, got, sent + 2);
  ASSERT_EQ(got.size(), static_cast<std::size_t>(sent));
  EXPECT_EQ(got[0].trigger_seq, 0u);
  EXPECT_EQ(got[0].mark_count, 2);
  EXPECT_NEAR(got[0].marks[0].x_px, 100.25f, 1.0f / 256);
  EXPECT_NEAR(got[0].marks[1].y_px, 900.75f, 1.0f / 256);
  const auto& c = rx.counters();
  EXPECT_EQ(c.decoded, static_cast<std::uint64_t>(sent));
  EXPECT_EQ(c.decode_errors.count(msg::DecodeError::kBadCrc), 1u);
  EXPECT_EQ(c.decode_errors.count(msg::DecodeError::kTooShort), 1u);
  EXPECT_EQ(c.datagram_seq_gaps, 1u);
}

// A unit still sending MarkObservations version 1 (no exposure_time_sigma_ns): refused, counted
// and named in the counters, whatever its CRC says.
TEST(UdpReceiver, AnOlderUnitsMessageVersionIsRefusedByName) {
  UdpReceiver rx;
  ASSERT_EQ(rx.open("127.0.0.1", 0), 0);
  Sender tx(rx.port());
  std::array<std::uint8_t, msg::kMaxDatagramBytes> buf{};
  const int n = msg::encode_datagram(observation(7), buf, 1);
  ASSERT_GT(n, 0);
  buf[4] = 1;  // header byte 4: message_version (docs/icd.md, section 3)
  const auto body = std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(n) - 4);
  bytes::BigEndianWriter crc(std::span<std::uint8_t>(buf.data() + n - 4, 4));
  crc.put_u32(msg::crc32(body));
  tx.send(std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(n)));
  std::vector<msg::MarkObservations> got;
  drain(rx, got, 1);
  EXPECT_TRUE(got.empty());
  EXPECT_EQ(rx.counters().decode_errors.count(msg::DecodeError::kBadVersion), 1u);
  std::string expected = "MarkObservations version 1 from unit ";  // appended: GCC 12
  expected += std::to_string(observation(7).unit_id);              // -Warray-bounds on +
  expected += " (this host reads version 2)";
  EXPECT_EQ(describe(rx.counters().last_refused_version), expected);
  EXPECT_EQ(describe(RefusedVersion{}), "");
}

TEST(UdpReceiver, RawHandlerSeesEveryDatagramAsSentWithItsVerdict) {
  // Raw recording: every datagram the socket delivers, valid, corrupted, too short or from a
  // sender that is not allowed, byte for byte as the sender sent it, before the decoded message.
  UdpReceiver rx;
  ASSERT_EQ(rx.open("127.0.0.1", 0), 0);
  ASSERT_EQ(rx.allow_source(1, "127.0.0.1"), 0);
  struct Raw {
    msg::RawObservation r;
    std::vector<std::uint8_t> bytes;
  };
  std::vector<Raw> raws;
  rx.set_raw_handler([&](const msg::RawObservation& r, std::span<const std::uint8_t> b) {
    raws.push_back({r, {b.begin(), b.end()}});
  });
  std::vector<std::vector<std::uint8_t>> sent;
  std::array<std::uint8_t, msg::kMaxDatagramBytes> buf{};
  auto send_from = [&](const char* from, std::vector<std::uint8_t> d) {
    Sender(rx.port(), from).send(d);
    sent.push_back(std::move(d));
  };
  for (std::uint32_t k = 0; k < 5; ++k) {
    const int n = msg::encode_datagram(observation(k), buf, k);
    send_from("127.0.0.1", {buf.begin(), buf.begin() + n});
  }
  int n = msg::encode_datagram(observation(5), buf, 5);
  std::vector<std::uint8_t> corrupt(buf.begin(), buf.begin() + n);
  corrupt[10] ^= 0x01;
  send_from("127.0.0.1", corrupt);
  send_from("127.0.0.1", {1, 2, 3});
  n = msg::encode_datagram(observation(6), buf, 6);
  send_from("127.0.0.2", {buf.begin(), buf.begin() + n});  // valid, from a foreign address
  std::vector<msg::MarkObservations> got;
  drain(rx, got, static_cast<int>(sent.size()));
  ASSERT_EQ(got.size(), 5u);
  ASSERT_EQ(raws.size(), sent.size());
  const std::int64_t now = time::tai_now_ns();
  for (std::size_t i = 0; i < sent.size(); ++i) {
    SCOPED_TRACE(i);
    const auto& r = raws[i].r;
    EXPECT_EQ(raws[i].bytes, sent[i]);
    EXPECT_EQ(r.message_bytes, sent[i].size());
    EXPECT_EQ(r.received_bytes, sent[i].size());
    EXPECT_EQ(r.source_kind, 0);
    EXPECT_EQ(r.source_address, i == 7 ? 0x7F000002u : 0x7F000001u);
    EXPECT_NE(r.source_port, 0);
    EXPECT_LE(r.arrival_tai_ns, now);
    EXPECT_GT(r.arrival_tai_ns, now - 10'000'000'000LL);
    const bool accepted = i < 5;
    EXPECT_EQ((r.flags & msg::raw_observation_flags::kAccepted) != 0, accepted);
    EXPECT_EQ(r.flags & msg::raw_observation_flags::kTruncated, 0);
    EXPECT_EQ(r.camera_id, accepted ? 3 : 0xFF);
  }
  EXPECT_EQ(raws[0].r.unit_id, 1);
  EXPECT_EQ(raws[5].r.decode_error, static_cast<std::uint8_t>(msg::DecodeError::kBadCrc));
  EXPECT_EQ(raws[6].r.decode_error, static_cast<std::uint8_t>(msg::DecodeError::kTooShort));
  EXPECT_EQ(raws[6].r.unit_id, 0xFF);  // too short to claim a unit
  EXPECT_EQ(raws[7].r.decode_error, kRawSpoofedSource);
}

TEST(UdpReceiver, BadAddressesAreErrorsNotCrashes) {
  UdpReceiver rx;
  EXPECT_EQ(rx.open("not-an-address", 5000), -EINVAL);
  EXPECT_EQ(rx.open("127.0.0.1", 0, "also-bad"), -EINVAL);
  CanFdReceiver can;
  EXPECT_EQ(can.open("no_such_can_if"), -ENODEV);
}

// Sends one observation to `group`:`port` out of the loopback interface.
void send_to_group(const char* group, std::uint16_t port, std::uint32_t seq) {
  const int fd = socket(AF_INET, SOCK_DGRAM, 0);
  in_addr ifa{};
  inet_pton(AF_INET, "127.0.0.1", &ifa);
  setsockopt(fd, IPPROTO_IP, IP_MULTICAST_IF, &ifa, sizeof ifa);
  sockaddr_in dst{};
  dst.sin_family = AF_INET;
  dst.sin_port = htons(port);
  inet_pton(AF_INET, group, &dst.sin_addr);
  std::array<std::uint8_t, msg::kMaxDatagramBytes> buf{};
  const int n = msg::encode_datagram(observation(seq), buf, 0);
  sendto(fd, buf.data(), static_cast<std::size_t>(n), 0, reinterpret_cast<sockaddr*>(&dst),
         sizeof dst);
  close(fd);
}

TEST(UdpReceiver, MulticastWithTheInterfaceAsBindAddressReceivesTheGroup) {
  // `--udp-bind 127.0.0.1 --udp-group G` (the host's configuration for a multicast FTI network):
  // a socket bound to the unicast address never sees the group's datagrams (before: nothing
  // arrived, silently). Now the socket binds the group and joins it on the bind address.
  UdpReceiver rx;
  const int rc = rx.open("127.0.0.1", 0, "239.255.42.98");
  ASSERT_EQ(rc, 0) << "multicast join on loopback failed: " << rc;
  send_to_group("239.255.42.98", rx.port(), 7);
  std::vector<msg::MarkObservations> got;
  drain(rx, got, 1);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].trigger_seq, 7u);
}

TEST(UdpReceiver, JoinsMulticastGroupOnLoopback) {
  UdpReceiver rx;
  const int rc = rx.open("0.0.0.0", 0, "239.255.42.99", "127.0.0.1");
  if (rc != 0) GTEST_SKIP() << "multicast join on loopback not possible here: " << rc;
  send_to_group("239.255.42.99", rx.port(), 1);
  std::vector<msg::MarkObservations> got;
  drain(rx, got, 1);
  if (got.empty()) GTEST_SKIP() << "no multicast route on loopback in this sandbox";
  EXPECT_EQ(got[0].trigger_seq, 1u);
}

void send_observations(Sender& tx, std::uint32_t first, int count) {
  std::array<std::uint8_t, msg::kMaxDatagramBytes> buf{};
  for (int k = 0; k < count; ++k) {
    const auto seq = first + static_cast<std::uint32_t>(k);
    const int n = msg::encode_datagram(observation(seq), buf, seq);
    ASSERT_GT(n, 0);
    tx.send(std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(n)));
  }
}

TEST(UdpReceiver, OnlyConfiguredUnitAndSourceCombinationsAreDelivered) {
  // Unit 1 is configured at 127.0.0.2: the same valid datagrams from 127.0.0.3 (another host),
  // and unit 1's datagrams are all the test sends, so any delivery from .3 is a spoof accepted.
  UdpReceiver rx;
  ASSERT_EQ(rx.open("127.0.0.1", 0), 0);
  ASSERT_EQ(rx.allow_source(1, "127.0.0.2"), 0);
  EXPECT_EQ(rx.allow_source(1, "not-an-address"), -EINVAL);
  EXPECT_EQ(rx.allow_source(255, "127.0.0.2"), -EINVAL);
  Sender genuine(rx.port(), "127.0.0.2");
  Sender forger(rx.port(), "127.0.0.3");
  send_observations(genuine, 0, 10);
  send_observations(forger, 1000, 7);
  std::vector<msg::MarkObservations> got;
  drain(rx, got, 17);
  ASSERT_EQ(got.size(), 10u);
  for (const auto& o : got)
    EXPECT_LT(o.trigger_seq, 10u) << "a forged datagram was delivered";
  EXPECT_EQ(rx.counters().spoofed_source, 7u);
  EXPECT_EQ(rx.counters().datagram_seq_gaps, 0u) << "the forger's counter disturbed the gaps";
}

void send_garbage(Sender& tx, int count, std::uint32_t seed) {
  std::array<std::uint8_t, 600> junk{};
  for (int i = 0; i < count; ++i) {
    for (auto& b : junk)
      b = static_cast<std::uint8_t>((seed = seed * 1664525u + 1013904223u) >> 24);
    if (i % 3 == 0) {  // valid-looking start: the storetrack magic, an unallowed unit, junk
      junk[0] = msg::kUdpMagic >> 8;
      junk[1] = msg::kUdpMagic & 0xFF;
      junk[5] = 200;
    }
    tx.send(std::span<const std::uint8_t>(junk.data(), 4 + (seed >> 8) % (junk.size() - 4)));
  }
}

void send_foreign_unit(Sender& tx, int count) {
  std::array<std::uint8_t, msg::kMaxDatagramBytes> buf{};
  for (int k = 0; k < count; ++k) {
    msg::MarkObservations o = observation(static_cast<std::uint32_t>(k));
    o.unit_id = 9;  // nobody configured unit 9; a valid datagram otherwise
    const int n = msg::encode_datagram(o, buf, static_cast<std::uint32_t>(k));
    ASSERT_GT(n, 0);
    tx.send(std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(n)));
  }
}

TEST(UdpReceiver, KernelFilterAdmitsOnlyAllowedUnitAndSourceCombinations) {
  // Unit 1 is allowed from 127.0.0.2 only. Forged (unit 1 from .3), foreign-unit (unit 9 from
  // .2) and garbage datagrams (a third with the magic) never reach the socket buffer: the
  // kernel counts them as drops, the host reads only the genuine ones.
  UdpReceiver rx;
  EXPECT_EQ(rx.install_kernel_filter(), -EBADF);
  ASSERT_EQ(rx.open("127.0.0.1", 0), 0);
  EXPECT_EQ(rx.install_kernel_filter(), -EINVAL) << "no allowed source: nothing to filter by";
  ASSERT_EQ(rx.allow_source(1, "127.0.0.2"), 0);
  ASSERT_EQ(rx.install_kernel_filter(), 0);
  EXPECT_EQ(rx.counters().kernel_filter_sources, 1u);
  Sender genuine(rx.port(), "127.0.0.2");
  Sender forger(rx.port(), "127.0.0.3");
  send_observations(genuine, 0, 10);
  send_observations(forger, 1000, 7);
  send_foreign_unit(genuine, 5);
  send_garbage(genuine, 30, 7);
  std::vector<msg::MarkObservations> got;
  drain(rx, got, 10);
  ASSERT_EQ(got.size(), 10u);
  for (const auto& o : got)
    EXPECT_LT(o.trigger_seq, 10u) << "a forged datagram was delivered";
  const auto& c = rx.counters();
  EXPECT_EQ(c.datagrams, 10u) << "only the genuine datagrams were queued";
  EXPECT_EQ(c.kernel_drops, 7u + 5u + 30u) << "every refused datagram counted by the kernel";
  EXPECT_EQ(c.spoofed_source, 0u);
  EXPECT_EQ(c.datagram_seq_gaps, 0u);
}

// Valid datagrams delivered when `flood` garbage datagrams arrive around each of them while
// the host does not read (a descheduled host), into a 128 KiB socket buffer.
int valid_delivered_under_flood(bool kernel_filter, int valid, int flood) {
  UdpReceiver rx;
  EXPECT_EQ(rx.open("127.0.0.1", 0, "", "", 128 << 10), 0);
  EXPECT_EQ(rx.allow_source(1, "127.0.0.1"), 0);
  if (kernel_filter) {
    EXPECT_EQ(rx.install_kernel_filter(), 0);
  }
  Sender tx(rx.port());
  for (int k = 0; k < valid; ++k) {
    send_garbage(tx, flood, static_cast<std::uint32_t>(k));
    send_observations(tx, static_cast<std::uint32_t>(k), 1);
  }
  int delivered = 0;
  for (int calls = 0; calls < 100; ++calls)
    rx.receive([&](const msg::AnyMessage&) { ++delivered; });
  const auto& c = rx.counters();
  EXPECT_EQ(c.datagrams + c.kernel_drops, static_cast<std::uint64_t>(valid * (flood + 1)))
      << "every datagram received or counted";
  return delivered;
}

TEST(UdpReceiver, KernelFilterKeepsTheSocketBufferForValidDatagramsUnderAFlood) {
  // 40 valid datagrams, each behind 10 garbage ones (a 10x flood), nobody reading: without
  // the filter the garbage fills the buffer and valid datagrams are dropped with it; with the
  // filter all 40 fit (40 x ~1.3 KiB of buffer accounting < 128 KiB).
  EXPECT_LT(valid_delivered_under_flood(false, 40, 10), 40) << "the flood must overflow the buffer";
  EXPECT_EQ(valid_delivered_under_flood(true, 40, 10), 40);
}

TEST(UdpReceiver, ReceiveReadsAtMostItsBoundPerCall) {
  // A flood waiting in the socket: one call reads kMaxDatagramsPerReceive and returns, so the
  // caller's loop gets to align and process; the rest is read by the next calls, none lost.
  UdpReceiver rx;
  ASSERT_EQ(rx.open("127.0.0.1", 0), 0);
  Sender tx(rx.port());
  const int sent = kMaxDatagramsPerReceive * 2 + 10;
  send_observations(tx, 0, sent);
  pollfd p{rx.fd(), POLLIN, 0};
  ASSERT_EQ(poll(&p, 1, 1000), 1);
  int delivered = 0;
  const auto count = [&](const msg::AnyMessage&) { ++delivered; };
  EXPECT_EQ(rx.receive(count), kMaxDatagramsPerReceive);
  EXPECT_EQ(delivered, kMaxDatagramsPerReceive);
  EXPECT_EQ(rx.counters().budget_exhausted, 1u);
  EXPECT_EQ(rx.receive(count), kMaxDatagramsPerReceive);
  EXPECT_EQ(rx.receive(count), 10);
  EXPECT_EQ(delivered, sent);
  EXPECT_EQ(rx.counters().budget_exhausted, 2u);
}

TEST(UdpReceiver, ReportsTheReceiveBufferTheKernelGranted) {
  // SO_RCVBUF is capped at net.core.rmem_max silently: the granted size is read back (and
  // forced past the cap where the process may), so the host can say what it got.
  UdpReceiver rx;
  ASSERT_EQ(rx.open("127.0.0.1", 0, "", "", 64 << 20), 0);
  const auto& c = rx.counters();
  EXPECT_EQ(c.receive_buffer_requested_bytes, 64u << 20);
  int granted = 0;
  socklen_t len = sizeof granted;
  ASSERT_EQ(getsockopt(rx.fd(), SOL_SOCKET, SO_RCVBUF, &granted, &len), 0);
  EXPECT_EQ(c.receive_buffer_bytes, static_cast<std::uint64_t>(granted / 2));
  EXPECT_GT(c.receive_buffer_bytes, 0u);
}

TEST(UdpReceiver, KernelDropsOfAFullSocketBufferAreCounted) {
  // A small receive buffer overflows on loopback (the sender never blocks): every datagram sent
  // is either received or counted as a kernel drop, at once, and still after later traffic.
  // SO_RXQ_OVFL reports drops only with the next datagram received, so the last burst before a
  // quiet link (a unit that stopped, the end of a run) left its drops uncounted (before: 0 at
  // the first check); the socket's own count (SO_MEMINFO) has them.
  UdpReceiver rx;
  ASSERT_EQ(rx.open("127.0.0.1", 0, "", "", 8192), 0);
  Sender tx(rx.port());
  const int sent = 400;
  send_observations(tx, 0, sent);
  int delivered = 0;
  for (int calls = 0; calls < 20; ++calls)
    rx.receive([&](const msg::AnyMessage&) { ++delivered; });
  EXPECT_GT(rx.counters().kernel_drops, 0u);
  EXPECT_EQ(static_cast<std::uint64_t>(delivered) + rx.counters().kernel_drops,
            static_cast<std::uint64_t>(sent));
  send_observations(tx, static_cast<std::uint32_t>(sent), 1);
  pollfd p{rx.fd(), POLLIN, 0};
  ASSERT_EQ(poll(&p, 1, 1000), 1);
  rx.receive([&](const msg::AnyMessage&) { ++delivered; });
  EXPECT_EQ(static_cast<std::uint64_t>(delivered) + rx.counters().kernel_drops,
            static_cast<std::uint64_t>(sent + 1));
}

}  // namespace
}  // namespace storetrack::ingest
