// iNET-X packet layout, the FTI parameter block round trip, and the CSV header/rows.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "fti_sample_factory.hpp"
#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/output/csv_writer.hpp"
#include "storetrack/output/inetx.hpp"

namespace storetrack::output {
namespace {

TEST(FtiParameterBlock, RoundTripIsBitExact) {
  std::mt19937_64 rng(5);
  for (std::uint32_t k = 0; k < 100; ++k) {
    const auto s = testing::make_sample(k, 1'800'000'000'000'000'000, rng);
    std::array<std::uint8_t, kFtiParameterBlockBytes> buf{};
    ASSERT_EQ(encode_fti_parameter_block(s, buf), 166);
    EXPECT_EQ(fti_parameter_block_error(buf), "");
    msg::FtiSample d{};
    ASSERT_EQ(decode_fti_parameter_block(buf, d), 0);
    EXPECT_EQ(std::memcmp(&d.correlation, &s.correlation, sizeof s.correlation), 0);
    EXPECT_EQ(d.exposure_mid_tai_ns, s.exposure_mid_tai_ns);
    EXPECT_EQ(d.x_m, s.x_m);
    EXPECT_EQ(d.u_roll_rad, s.u_roll_rad);
    EXPECT_EQ(d.status, s.status);
    EXPECT_EQ(d.u_budget_centroid_m, s.u_budget_centroid_m);
    EXPECT_EQ(d.u_budget_intrinsic_m, s.u_budget_intrinsic_m);
    EXPECT_EQ(d.u_budget_extrinsic_m, s.u_budget_extrinsic_m);
    EXPECT_EQ(d.u_budget_sync_m, s.u_budget_sync_m);
    EXPECT_EQ(d.u_budget_process_m, s.u_budget_process_m);
    EXPECT_EQ(d.coverage_factor, s.coverage_factor);
    // Bit-exact, NaN (no geometry) included.
    EXPECT_EQ(std::bit_cast<std::uint32_t>(d.clearance_m),
              std::bit_cast<std::uint32_t>(s.clearance_m));
    EXPECT_EQ(std::bit_cast<std::uint32_t>(d.u_clearance_m),
              std::bit_cast<std::uint32_t>(s.u_clearance_m));
    EXPECT_EQ(std::bit_cast<std::uint32_t>(d.clearance_lower_bound_m),
              std::bit_cast<std::uint32_t>(s.clearance_lower_bound_m));
    EXPECT_EQ(d.clearance_part, s.clearance_part);
  }
  std::array<std::uint8_t, 100> small{};
  EXPECT_EQ(encode_fti_parameter_block(msg::FtiSample{}, small), -ENOSPC);
}

// Version 3 appended the clearance at 152 (166 bytes); version 2 added u_budget_process at 144
// and moved coverage_factor to 148. A block of another version (of its own length or this one's)
// must be refused by its version, never decoded with this version's offsets.
TEST(FtiParameterBlock, OtherVersionsAreRefusedByName) {
  std::mt19937_64 rng(7);
  std::array<std::uint8_t, kFtiParameterBlockBytes> buf{};
  ASSERT_EQ(encode_fti_parameter_block(testing::make_sample(1, 0, rng), buf), 166);
  EXPECT_EQ(bytes::BigEndianReader(std::span(buf).subspan(18)).get_u16(), 3);
  msg::FtiSample d{};
  EXPECT_EQ(decode_fti_parameter_block(std::span(buf).first(152), d), -EINVAL);
  EXPECT_EQ(fti_parameter_block_error(std::span(buf).first(152)),
            "FTI parameter block version 3 of 152 bytes: needs 166");
  for (std::uint16_t version : {std::uint16_t{1}, std::uint16_t{2}}) {
    bytes::BigEndianWriter(std::span(buf).subspan(18)).put_u16(version);
    for (std::size_t bytes : {std::size_t{148}, std::size_t{152}, std::size_t{166}}) {
      EXPECT_EQ(decode_fti_parameter_block(std::span(buf).first(bytes), d), -EPROTO);
      EXPECT_EQ(fti_parameter_block_error(std::span(buf).first(bytes)),
                "FTI parameter block version " + std::to_string(version) +
                    ": this reader decodes only version 3 (166 bytes, docs/fti-output.md)");
    }
  }
  EXPECT_EQ(decode_fti_parameter_block(std::span(buf).first(19), d), -EINVAL);
}

// The block is the schema's generated FtiSample payload: its block_version is the schema
// constant (offset 18 = 8 + 4 + 4 x 1 + 2), refused when it differs, and the payload is exactly
// 166 bytes.
TEST(FtiParameterBlock, GeneratedCodecChecksVersionAndLength) {
  static_assert(msg::kFtiSampleBlockVersionOffset == 18);
  std::mt19937_64 rng(3);
  std::array<std::uint8_t, kFtiParameterBlockBytes + 1> buf{};
  ASSERT_EQ(encode_fti_parameter_block(testing::make_sample(2, 0, rng), buf), 166);
  msg::FtiSample d{};
  bytes::BigEndianReader whole{std::span<const std::uint8_t>(buf).first(166)};
  EXPECT_EQ(msg::unpack_payload(whole, d), msg::DecodeError::kNone);
  bytes::BigEndianReader longer{std::span<const std::uint8_t>(buf)};
  EXPECT_EQ(msg::unpack_payload(longer, d), msg::DecodeError::kBadLength);
  bytes::BigEndianReader shorter{std::span<const std::uint8_t>(buf).first(165)};
  EXPECT_EQ(msg::unpack_payload(shorter, d), msg::DecodeError::kBadLength);
  buf[19] = 2;  // block_version 2
  bytes::BigEndianReader other{std::span<const std::uint8_t>(buf).first(166)};
  EXPECT_EQ(msg::unpack_payload(other, d), msg::DecodeError::kBadVersion);
}

TEST(Inetx, HeaderFieldsAreBigEndianAtTheDocumentedOffsets) {
  std::mt19937_64 rng(9);
  auto s = testing::make_sample(3, 1'800'000'000'123'456'789, rng);
  s.status = 0;  // invalid sample: PIF data-error bit
  std::array<std::uint8_t, kInetxPacketBytes> buf{};
  ASSERT_EQ(encode_inetx_packet(s, 0xDC000001u, 77, buf), 194);
  EXPECT_EQ(buf[0], 0x11);  // control word 0x11000000
  EXPECT_EQ(buf[4], 0xDC);  // stream id MSB first
  EXPECT_EQ(buf[11], 77);
  EXPECT_EQ(buf[15], 194);
  InetxHeader h{};
  ASSERT_EQ(decode_inetx_header(buf, h), 0);
  EXPECT_EQ(h.control_word, kInetxControlWord);
  EXPECT_EQ(h.stream_id, 0xDC000001u);
  EXPECT_EQ(h.sequence, 77u);
  EXPECT_EQ(h.packet_length, 194u);
  const std::int64_t t = s.exposure_mid_tai_ns;
  EXPECT_EQ(h.ptp_seconds, static_cast<std::uint32_t>(t / 1'000'000'000));
  EXPECT_EQ(h.ptp_nanoseconds, static_cast<std::uint32_t>(t % 1'000'000'000));
  EXPECT_EQ(h.pif, kInetxPifDataError);
  EXPECT_EQ(decode_inetx_header(std::span(buf).first(100), h), -EINVAL);
}

TEST(Inetx, EndpointParsing) {
  std::string a;
  std::uint16_t p = 0;
  EXPECT_TRUE(parse_ipv4_endpoint("239.1.2.3:6000", a, p));
  EXPECT_EQ(a, "239.1.2.3");
  EXPECT_EQ(p, 6000);
  EXPECT_FALSE(parse_ipv4_endpoint("239.1.2.3", a, p));
  EXPECT_FALSE(parse_ipv4_endpoint("239.1.2.3:70000", a, p));
  EXPECT_FALSE(parse_ipv4_endpoint("host:12", a, p));
  InetxSender tx;
  EXPECT_EQ(tx.open("nonsense", 1), -EINVAL);
}

TEST(FtiCsv, HeaderNamesEveryColumnWithAUnit) {
  const auto path =
      std::filesystem::temp_directory_path() / ("st_fti_" + std::to_string(::getpid()) + ".csv");
  FtiCsvWriter w;
  ASSERT_EQ(w.open(path.string()), 0);
  std::mt19937_64 rng(2);
  for (std::uint32_t k = 0; k < 10; ++k)
    ASSERT_EQ(w.write(testing::make_sample(k, 0, rng)), 0);
  ASSERT_EQ(w.close(), 0);
  std::ifstream in(path);
  std::string header;
  std::getline(in, header);
  const auto columns = fti_csv_columns();
  EXPECT_EQ(columns.size(), 19u + 15u + 6u + 4u);
  std::size_t count = 1;
  for (char c : header)
    count += c == ',';
  EXPECT_EQ(count, columns.size());
  for (const auto& c : columns) {
    EXPECT_NE(c.find(" ["), std::string::npos) << c << " has no unit";
    EXPECT_NE(header.find(c), std::string::npos);
  }
  // The budget columns read back (9 significant digits round-trip a float exactly).
  const auto column = [&](const std::string& name) {
    return static_cast<std::size_t>(std::find(columns.begin(), columns.end(), name) -
                                    columns.begin());
  };
  const std::size_t sync_col = column("u_budget_sync [m]");
  const std::size_t process_col = column("u_budget_process [m]");
  ASSERT_EQ(process_col, sync_col + 1);
  ASSERT_EQ(column("coverage_factor [1]"), process_col + 1);
  const std::size_t clearance_col = column("clearance [m]");
  ASSERT_EQ(clearance_col, process_col + 2);
  ASSERT_EQ(column("clearance_part [1]"), clearance_col + 3);
  std::mt19937_64 replay(2);
  std::string row;
  std::uint32_t rows = 0;
  while (std::getline(in, row)) {
    std::vector<std::string> fields;
    std::stringstream ss(row);
    for (std::string f; std::getline(ss, f, ',');)
      fields.push_back(f);
    EXPECT_EQ(fields.size(), columns.size());
    const msg::FtiSample s = testing::make_sample(rows, 0, replay);
    if (fields.size() == columns.size()) {
      EXPECT_EQ(std::strtof(fields[sync_col].c_str(), nullptr), s.u_budget_sync_m);
      EXPECT_EQ(std::strtof(fields[process_col].c_str(), nullptr), s.u_budget_process_m);
      // The clearance columns: NaN reads back as NaN ("nan"), the part as its integer.
      const float clearance_sent[] = {s.clearance_m, s.u_clearance_m, s.clearance_lower_bound_m};
      for (std::size_t i = 0; i < 3; ++i) {
        const float read = std::strtof(fields[clearance_col + i].c_str(), nullptr);
        if (std::isnan(clearance_sent[i]))
          EXPECT_TRUE(std::isnan(read)) << columns[clearance_col + i];
        else
          EXPECT_EQ(read, clearance_sent[i]) << columns[clearance_col + i];
      }
      EXPECT_EQ(std::stoul(fields[clearance_col + 3]), s.clearance_part);
      // Every float column, the 15 correlations included (they were written with 6 digits:
      // a correlation of 0.123456789 read back as 0.123457), reads back the very float sent.
      const std::vector<float> sent = {s.x_m,       s.y_m,       s.z_m,         s.yaw_rad,
                                       s.pitch_rad, s.roll_rad,  s.u_x_m,       s.u_y_m,
                                       s.u_z_m,     s.u_yaw_rad, s.u_pitch_rad, s.u_roll_rad};
      const std::size_t first_float = column("x [m]");
      for (std::size_t i = 0; i < sent.size(); ++i)
        EXPECT_EQ(std::strtof(fields[first_float + i].c_str(), nullptr), sent[i])
            << columns[first_float + i];
      const std::size_t first_correlation = first_float + sent.size();
      for (std::size_t i = 0; i < 15; ++i)
        EXPECT_EQ(std::strtof(fields[first_correlation + i].c_str(), nullptr), s.correlation[i])
            << columns[first_correlation + i];
    }
    ++rows;
  }
  EXPECT_EQ(rows, 10u);
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace storetrack::output
