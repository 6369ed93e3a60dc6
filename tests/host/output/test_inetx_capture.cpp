// iNET-X checked by capture: tshark listens on loopback with a capture filter on our port while
// InetxSender sends real samples; the captured UDP payloads are then compared field by field
// with what was sent. Exits 77 (ctest: skipped) with the reason when capture is impossible.
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>
#include <cmath>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>
#include <thread>

#include "fti_sample_factory.hpp"
#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/output/inetx.hpp"

namespace storetrack::output {
namespace {

namespace fs = std::filesystem;

[[noreturn]] void skip(const std::string& why) {
  std::cout << "SKIPPED: " << why << std::endl;
  std::_Exit(77);
}

std::vector<std::uint8_t> from_hex(const std::string& hex) {
  std::vector<std::uint8_t> out;
  std::string digits;
  for (char c : hex)
    if (std::isxdigit(static_cast<unsigned char>(c))) digits += c;
  for (std::size_t i = 0; i + 1 < digits.size(); i += 2)
    out.push_back(static_cast<std::uint8_t>(std::stoi(digits.substr(i, 2), nullptr, 16)));
  return out;
}

TEST(InetxCapture, TsharkSeesTheHeaderAndPayloadThatWereSent) {
  if (std::system("command -v tshark >/dev/null 2>&1") != 0) skip("tshark is not installed");
  const std::uint16_t port = static_cast<std::uint16_t>(41000 + ::getpid() % 2000);
  const fs::path dir = fs::temp_directory_path() / ("st_inetx_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const fs::path pcap = dir / "capture.pcapng";
  const fs::path log = dir / "tshark.log";
  const pid_t tshark = fork();
  ASSERT_GE(tshark, 0);
  if (tshark == 0) {
    const std::string filter = "udp port " + std::to_string(port);
    std::freopen(log.c_str(), "w", stderr);
    std::freopen("/dev/null", "w", stdout);
    execlp("tshark", "tshark", "-i", "lo", "-f", filter.c_str(), "-w", pcap.c_str(), nullptr);
    std::_Exit(127);
  }
  // Wait for "Capturing on" (dumpcap has opened the interface) before sending anything.
  bool capturing = false;
  for (int i = 0; i < 150 && !capturing; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    std::ifstream in(log);
    std::stringstream ss;
    ss << in.rdbuf();
    capturing = ss.str().find("Capturing on") != std::string::npos;
    int status = 0;
    if (waitpid(tshark, &status, WNOHANG) == tshark)
      skip("tshark could not capture on lo: " + ss.str());
  }
  if (!capturing) {
    kill(tshark, SIGKILL);
    waitpid(tshark, nullptr, 0);
    skip("tshark did not start capturing on lo within 15 s");
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(300));

  InetxSender tx;
  ASSERT_EQ(tx.open("127.0.0.1:" + std::to_string(port), 0x5354'0001u), 0);
  std::mt19937_64 rng(11);
  std::vector<msg::FtiSample> sent;
  for (std::uint32_t k = 0; k < 50; ++k) {
    sent.push_back(testing::make_sample(k, 1'800'000'000'000'000'000, rng));
    ASSERT_EQ(tx.send(sent.back()), 0);
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  kill(tshark, SIGINT);
  waitpid(tshark, nullptr, 0);

  const std::string cmd = "tshark -r '" + pcap.string() +
                          "' -T fields -e udp.dstport -e udp.length -e data.data 2>/dev/null "
                          "-d udp.port==" +
                          std::to_string(port) + ",data";
  FILE* pipe = popen(cmd.c_str(), "r");
  ASSERT_NE(pipe, nullptr);
  std::vector<std::vector<std::uint8_t>> payloads;
  char line[8192];
  while (std::fgets(line, sizeof line, pipe)) {
    std::istringstream fields(line);
    int dstport = 0, udp_length = 0;
    std::string hex;
    fields >> dstport >> udp_length >> hex;
    EXPECT_EQ(dstport, port);
    EXPECT_EQ(udp_length, 8 + 194);
    payloads.push_back(from_hex(hex));
  }
  pclose(pipe);
  ASSERT_EQ(payloads.size(), sent.size()) << "captured " << payloads.size() << " packets";
  for (std::size_t i = 0; i < sent.size(); ++i) {
    const auto& p = payloads[i];
    ASSERT_EQ(p.size(), kInetxPacketBytes);
    InetxHeader h{};
    ASSERT_EQ(decode_inetx_header(p, h), 0);
    EXPECT_EQ(h.control_word, 0x11000000u);
    EXPECT_EQ(h.stream_id, 0x5354'0001u);
    EXPECT_EQ(h.sequence, i);
    EXPECT_EQ(h.packet_length, 194u);
    const std::int64_t t = sent[i].exposure_mid_tai_ns;
    EXPECT_EQ(h.ptp_seconds, static_cast<std::uint32_t>(t / 1'000'000'000));
    EXPECT_EQ(h.ptp_nanoseconds, static_cast<std::uint32_t>(t % 1'000'000'000));
    EXPECT_EQ(h.pif, (sent[i].status & msg::fti_status::kValid) ? 0u : kInetxPifDataError);
    // Payload parameters at the documented offsets (docs/fti-output.md), decoded by hand.
    const auto b = std::span<const std::uint8_t>(p).subspan(28);
    auto at = [&b](std::size_t offset) { return bytes::BigEndianReader(b.subspan(offset)); };
    EXPECT_EQ(static_cast<std::int64_t>(at(0).get_u64()), t);
    EXPECT_EQ(at(8).get_u32(), sent[i].trigger_seq);
    EXPECT_EQ(b[13], sent[i].cameras_used);
    EXPECT_EQ(b[14], sent[i].marks_used);
    EXPECT_EQ(at(16).get_u16(), sent[i].status);
    EXPECT_EQ(at(20).get_f32(), sent[i].x_m);
    EXPECT_EQ(at(28).get_f32(), sent[i].z_m);
    EXPECT_EQ(at(40).get_f32(), sent[i].roll_rad);
    EXPECT_EQ(at(44).get_f32(), sent[i].u_x_m);
    EXPECT_EQ(at(68).get_f32(), sent[i].correlation[0]);
    EXPECT_EQ(at(18).get_u16(), 3);  // block version
    EXPECT_EQ(at(140).get_f32(), sent[i].u_budget_sync_m);
    EXPECT_EQ(at(144).get_f32(), sent[i].u_budget_process_m);
    EXPECT_EQ(at(148).get_f32(), 2.0f);
    EXPECT_EQ(at(164).get_u16(), sent[i].clearance_part);
    if (!std::isnan(sent[i].clearance_m)) {
      EXPECT_EQ(at(152).get_f32(), sent[i].clearance_m);
      EXPECT_EQ(at(156).get_f32(), sent[i].u_clearance_m);
      EXPECT_EQ(at(160).get_f32(), sent[i].clearance_lower_bound_m);
    }
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace storetrack::output
