// Independent check of the ICD byte layouts: tests/common/msg/fuzz_seeds/make_seeds.py builds
// datagrams and CAN FD frames from docs/icd.md with Python's struct and zlib.crc32; the C++
// decoders must accept them and read the values the script put in.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <vector>

#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/msg/canfd_codec.hpp"
#include "storetrack/msg/udp_codec.hpp"

namespace storetrack::msg {
namespace {

std::filesystem::path seeds_dir() {
  const char* dir = std::getenv("STORETRACK_MSG_SEEDS");
  return dir != nullptr ? dir : "";
}

std::vector<std::uint8_t> read_file(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void expect_script_marks(const MarkObservations& m) {
  EXPECT_EQ(m.unit_id, 3);
  EXPECT_EQ(m.camera_id, 1);
  EXPECT_EQ(m.trigger_seq, 0x1234u);
  EXPECT_EQ(m.exposure_start_tai_ns, 1'800'000'000'000'000'000);
  EXPECT_EQ(m.exposure_start_mono_ns, 5'000'000'000);
  EXPECT_EQ(m.exposure_duration_ns, 200'000u);
  EXPECT_EQ(m.clock_state, 2);
  EXPECT_EQ(m.exposure_time_sigma_ns, 1'250u);
  for (std::size_t i = 0; i < m.mark_count; ++i) {
    EXPECT_FLOAT_EQ(m.marks[i].x_px, static_cast<float>(100 + 37 * i) / 256.0f - 0.5f);
    EXPECT_FLOAT_EQ(m.marks[i].y_px, static_cast<float>(50 + 11 * i) / 256.0f - 0.5f);
    EXPECT_NEAR(m.marks[i].sigma_px, 0.001 * std::exp2(40.0 / 16.0), 1e-7);
    EXPECT_EQ(m.marks[i].peak, 200);
    EXPECT_FLOAT_EQ(m.marks[i].diameter_px, 8.0f);
    EXPECT_EQ(m.marks[i].flags, i & 0xF);
  }
}

void expect_script_health(const UnitHealth& h) {
  EXPECT_EQ(h.unit_id, 3);
  EXPECT_EQ(h.uptime_s, 100u);
  EXPECT_EQ(h.ptp_offset_ns, -20);
  EXPECT_EQ(h.sensor_temp_cdeg, 4200);
  EXPECT_EQ(h.link_tx_dropped, 8u);
  EXPECT_EQ(h.centroid_time_us_max, 900);
  EXPECT_EQ(h.status, unit_status::kCapturing);
}

TEST(MsgIcdVectors, UdpDatagramsBuiltFromTheIcdDecode) {
  const auto dir = seeds_dir() / "udp";
  ASSERT_TRUE(std::filesystem::is_directory(dir)) << dir;
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    const auto bytes = read_file(entry.path());
    ASSERT_GT(bytes.size(), 1u);
    AnyMessage any;
    ASSERT_EQ(decode_datagram(std::span(bytes).subspan(1), any), DecodeError::kNone)
        << entry.path();
    if (const auto* m = std::get_if<MarkObservations>(&any)) expect_script_marks(*m);
    if (const auto* h = std::get_if<UnitHealth>(&any)) expect_script_health(*h);
    ++files;
  }
  EXPECT_EQ(files, 5);
}

TEST(MsgIcdVectors, CanFdFramesBuiltFromTheIcdReassemble) {
  const auto dir = seeds_dir() / "canfd";
  ASSERT_TRUE(std::filesystem::is_directory(dir)) << dir;
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.path().filename().string().rfind("raw_", 0) != 0) continue;
    const auto bytes = read_file(entry.path());
    CanFdReassembler reassembler;
    std::optional<AnyMessage> done;
    bytes::BigEndianReader r{std::span<const std::uint8_t>(bytes).subspan(1)};
    while (r.remaining() > 0) {
      CanFdFrame f;
      f.can_id = r.get_u32();
      f.len = r.get_u8();
      r.get_u16();  // time step, for the fuzzer
      // A seed file names the frame length itself: never write past the 64-byte payload.
      ASSERT_LE(f.len, sizeof(f.data)) << entry.path();
      for (std::size_t i = 0; i < f.len; ++i)
        f.data[i] = r.get_u8();
      ASSERT_TRUE(r.ok());
      ASSERT_EQ(reassembler.push(f, 0, done), DecodeError::kNone) << entry.path();
    }
    ASSERT_TRUE(done.has_value()) << entry.path();
    if (const auto* m = std::get_if<MarkObservations>(&*done)) expect_script_marks(*m);
    if (const auto* h = std::get_if<UnitHealth>(&*done)) expect_script_health(*h);
    ++files;
  }
  EXPECT_EQ(files, 5);
}

}  // namespace
}  // namespace storetrack::msg
