// The Chapter 10 writer's files validated by the INDEPENDENT reader (storetrack::ch10read, its
// own parsing written from IRIG 106-17 Chapter 11): TMATS first, header and data checksums,
// sequence numbers per channel, 1 Hz time packets matching the samples' UTC seconds, every
// message with its subchannel, time stamp and values, and a file truncated mid-packet.
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>
#include <cmath>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>

#include "fti_sample_factory.hpp"
#include "storetrack/output/chapter10_reader.hpp"
#include "storetrack/output/chapter10_writer.hpp"

namespace storetrack::output {
namespace {

namespace fs = std::filesystem;

// 2027-03-01T12:00:00 UTC + 0.6 s, as TAI ns; samples then cross several UTC seconds.
constexpr std::int64_t kUtc0 = 1'803'902'400;  // seconds since 1970, 2027-03-01 12:00:00 UTC
constexpr std::int64_t kT0Tai = (kUtc0 + 37) * 1'000'000'000LL + 600'000'000;

fs::path temp_file(const std::string& name) {
  return fs::temp_directory_path() / (name + "_" + std::to_string(::getpid()) + ".ch10");
}

struct Written {
  std::vector<msg::FtiSample> samples;
  Chapter10Counters counters;
};

Written write_file(const fs::path& path, int n, bool checksum, int per_packet) {
  std::mt19937_64 rng(7);
  Chapter10Config cfg;
  cfg.stores = {{1, "left"}, {2, "right"}};
  cfg.data_checksum = checksum;
  cfg.max_messages_per_packet = per_packet;
  cfg.sync = Chapter10Sync::kNone;
  Chapter10Writer w;
  EXPECT_EQ(w.open(path.string(), cfg), 0);
  Written out;
  for (int k = 0; k < n; ++k) {
    out.samples.push_back(testing::make_sample(static_cast<std::uint32_t>(k), kT0Tai, rng,
                                               static_cast<std::uint8_t>(1 + k % 2)));
    EXPECT_EQ(w.write(out.samples.back()), 0);
  }
  EXPECT_EQ(w.close(), 0);
  out.counters = w.counters();
  return out;
}

void check_file(const ch10read::File& f, const std::vector<msg::FtiSample>& samples,
                std::size_t expect_messages, bool checksum) {
  ASSERT_FALSE(f.packets.empty());
  // TMATS setup record first, channel 0, Computer-Generated Data Format 1.
  const auto& tmats_packet = f.packets.front();
  EXPECT_EQ(tmats_packet.channel_id, 0);
  EXPECT_EQ(tmats_packet.data_type, 0x01);
  const auto tmats = ch10read::decode_tmats(tmats_packet);
  ASSERT_TRUE(tmats);
  EXPECT_NE(tmats->find("G\\106:17;"), std::string::npos);
  EXPECT_NE(tmats->find("R-1\\CDT-2:MSGIN;"), std::string::npos);
  EXPECT_NE(tmats->find("subchannel 2 = store right"), std::string::npos);

  std::map<int, int> next_sequence;
  std::size_t messages = 0;
  std::int64_t rtc_epoch_utc = INT64_MIN;
  std::uint64_t epoch_rtc = 0;
  int time_packets = 0;
  std::int64_t last_time_utc = INT64_MIN;
  for (const auto& p : f.packets) {
    EXPECT_TRUE(p.header_checksum_ok);
    EXPECT_EQ(p.data_checksum_bits, checksum ? 32 : 0);
    EXPECT_TRUE(p.data_checksum_ok) << "packet at " << p.file_offset;
    EXPECT_EQ(p.data_type_version, 0x08);
    EXPECT_EQ(p.packet_length % 4, 0u);
    if (next_sequence.count(p.channel_id)) {
      EXPECT_EQ(p.sequence_number, static_cast<std::uint8_t>(next_sequence[p.channel_id]));
    }
    next_sequence[p.channel_id] = (p.sequence_number + 1) % 256;
    if (p.data_type == 0x11) {
      const auto t = ch10read::decode_time_f1(p);
      ASSERT_TRUE(t);
      EXPECT_TRUE(t->month_year_format);
      EXPECT_EQ(t->millisecond, 0);
      EXPECT_EQ(t->year, 2027);
      if (last_time_utc != INT64_MIN) {
        EXPECT_EQ(t->utc_epoch_seconds, last_time_utc + 1);
      }
      last_time_utc = t->utc_epoch_seconds;
      if (rtc_epoch_utc == INT64_MIN) {
        rtc_epoch_utc = t->utc_epoch_seconds;
        epoch_rtc = p.relative_time_counter;
      }
      // 10 MHz counter: exactly 10^7 ticks per second between time packets.
      EXPECT_EQ(p.relative_time_counter - epoch_rtc,
                static_cast<std::uint64_t>(t->utc_epoch_seconds - rtc_epoch_utc) * 10'000'000u);
      ++time_packets;
    } else if (p.data_type == 0x30) {
      std::string error;
      const auto msgs = ch10read::decode_message_f0(p, &error);
      ASSERT_TRUE(msgs) << error;
      ASSERT_FALSE(msgs->empty());
      EXPECT_EQ(p.relative_time_counter, msgs->front().intra_packet_time);
      for (const auto& m : *msgs) {
        ASSERT_LT(messages, samples.size());
        const msg::FtiSample& s = samples[messages++];
        EXPECT_EQ(m.subchannel, s.store_id);
        EXPECT_EQ(m.data_error, (s.status & msg::fti_status::kValid) == 0);
        // The message time stamp is the exposure mid-point on the 10 MHz counter.
        const std::int64_t t_utc_ns = s.exposure_mid_tai_ns - 37'000'000'000LL;
        EXPECT_EQ(m.intra_packet_time - epoch_rtc,
                  static_cast<std::uint64_t>((t_utc_ns - rtc_epoch_utc * 1'000'000'000LL) / 100));
        const auto b = ch10read::decode_fti_block(m.bytes);
        ASSERT_TRUE(b);
        EXPECT_EQ(b->version, 3);
        EXPECT_EQ(b->trigger_seq, s.trigger_seq);
        EXPECT_EQ(b->exposure_mid_tai_ns, s.exposure_mid_tai_ns);
        EXPECT_EQ(b->store_id, s.store_id);
        EXPECT_EQ(b->cameras_used, s.cameras_used);
        EXPECT_EQ(b->marks_used, s.marks_used);
        EXPECT_EQ(b->status, s.status);
        EXPECT_EQ(b->pose[0], s.x_m);
        EXPECT_EQ(b->pose[5], s.roll_rad);
        EXPECT_EQ(b->uncertainty[2], s.u_z_m);
        EXPECT_EQ(b->correlation[14], s.correlation[14]);
        EXPECT_EQ(b->budget[3], s.u_budget_sync_m);
        EXPECT_EQ(b->budget[4], s.u_budget_process_m);
        EXPECT_EQ(b->coverage_factor, 2.0);
        if (std::isnan(s.clearance_m)) {
          EXPECT_TRUE(std::isnan(b->clearance_m));
          EXPECT_TRUE(std::isnan(b->clearance_lower_bound_m));
        } else {
          EXPECT_EQ(b->clearance_m, s.clearance_m);
          EXPECT_EQ(b->u_clearance_m, s.u_clearance_m);
          EXPECT_EQ(b->clearance_lower_bound_m, s.clearance_lower_bound_m);
        }
        EXPECT_EQ(b->clearance_part, s.clearance_part);
      }
    } else {
      EXPECT_EQ(p.data_type, 0x01) << "unexpected data type";
    }
  }
  EXPECT_EQ(messages, expect_messages);
  if (expect_messages == samples.size()) {
    // Samples span 0.6 s .. 0.6 + n * 2.5 ms: one time packet per UTC second touched.
    const std::int64_t first_s = (samples.front().exposure_mid_tai_ns / 1'000'000'000LL) - 37;
    const std::int64_t last_s = (samples.back().exposure_mid_tai_ns / 1'000'000'000LL) - 37;
    EXPECT_EQ(time_packets, last_s - first_s + 1);
    EXPECT_EQ(rtc_epoch_utc, kUtc0);
  }
}

TEST(Chapter10, WriterFileValidatesWithIndependentReader) {
  const auto path = temp_file("st_ch10_full");
  const Written w = write_file(path, 1000, true, 10);
  const auto f = ch10read::read_file(path.string());
  EXPECT_TRUE(f.stop_reason.empty()) << f.stop_reason;
  EXPECT_FALSE(f.truncated);
  EXPECT_EQ(f.bytes_in_whole_packets, fs::file_size(path));
  check_file(f, w.samples, w.samples.size(), true);
  EXPECT_EQ(w.counters.messages_written, 1000u);
  EXPECT_EQ(w.counters.time_packets, 4u);  // 12:00:00 .. 12:00:03
  fs::remove(path);
}

// Chapter10Config::comments (a reprocessed recording's provenance): each a G\COM attribute after
// the writer's own, a ';' (the attribute terminator) written as ','; the file still validates.
TEST(Chapter10, CommentsAreTmatsComments) {
  const auto path = temp_file("st_ch10_comments");
  Chapter10Config cfg;
  cfg.sync = Chapter10Sync::kNone;
  cfg.comments = {"reprocessed from 'a;b.ch10'", "second"};
  Chapter10Writer w;
  ASSERT_EQ(w.open(path.string(), cfg), 0);
  ASSERT_EQ(w.close(), 0);
  const auto f = ch10read::read_file(path.string());
  ASSERT_FALSE(f.packets.empty());
  EXPECT_TRUE(f.stop_reason.empty()) << f.stop_reason;
  const auto tmats = ch10read::decode_tmats(f.packets.front());
  ASSERT_TRUE(tmats);
  const std::size_t first = tmats->find("G\\COM:reprocessed from 'a,b.ch10';");
  ASSERT_NE(first, std::string::npos) << *tmats;
  EXPECT_GT(tmats->find("G\\COM:second;"), first);
  EXPECT_GT(first, tmats->find("G\\COM:channel"));  // after the writer's own
  fs::remove(path);
}

TEST(Chapter10, WithoutDataChecksumAndOneMessagePerPacket) {
  const auto path = temp_file("st_ch10_nock");
  const Written w = write_file(path, 300, false, 1);
  const auto f = ch10read::read_file(path.string());
  EXPECT_TRUE(f.stop_reason.empty()) << f.stop_reason;
  check_file(f, w.samples, w.samples.size(), false);
  EXPECT_EQ(w.counters.message_packets, 300u);
  EXPECT_GT(f.packets.size(), 256u);  // sequence numbers wrapped at 255 and were checked
  fs::remove(path);
}

TEST(Chapter10, FileCutMidPacketIsReadableUpToTheLastWholePacket) {
  const auto path = temp_file("st_ch10_cut");
  const Written w = write_file(path, 400, true, 5);
  const auto whole = ch10read::read_file(path.string());
  ASSERT_TRUE(whole.stop_reason.empty());
  std::ifstream in(path, std::ios::binary);
  std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                                  std::istreambuf_iterator<char>());
  std::mt19937_64 rng(3);
  for (int trial = 0; trial < 50; ++trial) {
    // Cut anywhere after the TMATS packet: inside a header, a body or a trailer.
    std::uniform_int_distribution<std::size_t> at(whole.packets[1].file_offset + 1,
                                                  bytes.size() - 1);
    const std::size_t cut = at(rng);
    const auto f = ch10read::parse(std::span(bytes.data(), cut));
    std::size_t whole_before = 0;
    std::size_t messages_before = 0;
    for (const auto& p : whole.packets) {
      if (p.file_offset + p.packet_length > cut) break;
      ++whole_before;
      if (p.data_type == 0x30) messages_before += ch10read::decode_message_f0(p)->size();
    }
    EXPECT_EQ(f.packets.size(), whole_before) << "cut at " << cut;
    const bool on_boundary = f.bytes_in_whole_packets == cut;
    EXPECT_EQ(f.truncated, !on_boundary);
    check_file(f, w.samples, messages_before, true);
  }
  // A flipped bit in a body is caught by the data checksum, in a header by the header checksum.
  auto corrupt = bytes;
  corrupt[whole.packets[3].file_offset + 30] ^= 0x01;
  const auto f = ch10read::parse(corrupt);
  EXPECT_FALSE(f.packets[3].data_checksum_ok);
  corrupt = bytes;
  corrupt[whole.packets[3].file_offset + 5] ^= 0x01;
  EXPECT_EQ(ch10read::parse(corrupt).packets.size(), 3u);
  fs::remove(path);
}

TEST(Chapter10, CrashLosesAtMostTheLastPacket) {
  // A child process writes with fdatasync per packet and is killed mid-stream; the file it
  // leaves is read completely up to the last whole packet.
  const auto path = temp_file("st_ch10_kill");
  int pipefd[2];
  ASSERT_EQ(pipe(pipefd), 0);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    close(pipefd[0]);
    std::mt19937_64 rng(1);
    Chapter10Config cfg;
    cfg.max_messages_per_packet = 1;
    cfg.sync = Chapter10Sync::kEveryPacket;
    Chapter10Writer w;
    w.open(path.string(), cfg);
    for (std::uint32_t k = 0;; ++k) {
      w.write(testing::make_sample(k, kT0Tai, rng));
      if (k == 50) {
        const char c = 1;
        (void)!write(pipefd[1], &c, 1);
      }
    }
  }
  close(pipefd[1]);
  char c = 0;
  ASSERT_EQ(read(pipefd[0], &c, 1), 1);
  usleep(20'000);
  kill(child, SIGKILL);
  waitpid(child, nullptr, 0);
  close(pipefd[0]);
  const auto f = ch10read::read_file(path.string());
  EXPECT_GT(f.packets.size(), 50u);
  // At most one partial packet at the end, everything before it intact.
  EXPECT_GE(f.bytes_in_whole_packets + 24 + 4 + 12 + 166 + 4, fs::file_size(path));
  for (const auto& p : f.packets)
    EXPECT_TRUE(p.data_checksum_ok);
  fs::remove(path);
}

TEST(Chapter10, UtcCalendarFromTai) {
  const auto c = utc_calendar_from_tai(kT0Tai);
  EXPECT_EQ(c.year, 2027);
  EXPECT_EQ(c.month, 3);
  EXPECT_EQ(c.day, 1);
  EXPECT_EQ(c.hour, 12);
  EXPECT_EQ(c.minute, 0);
  EXPECT_EQ(c.second, 0);
  EXPECT_EQ(c.millisecond, 600);
}

TEST(Chapter10, UnwritablePathIsAnError) {
  Chapter10Writer w;
  EXPECT_LT(w.open("/nonexistent-dir/x.ch10", Chapter10Config{}), 0);
  EXPECT_EQ(w.write(msg::FtiSample{}), -EBADF);
  EXPECT_THROW(ch10read::read_file("/nonexistent-dir/x.ch10"), std::runtime_error);
}

// The reader decodes block version 3 (166 bytes) only: a version-1 block (148 bytes, no
// u_budget_process) or a version-2 block (152 bytes, no clearance) is refused with the version
// named, never read with version 3's offsets.
TEST(Chapter10Reader, FtiBlockOfAnotherVersionIsRefusedByName) {
  std::vector<std::uint8_t> block(148, 0);
  block[19] = 1;  // block_version 1, big-endian at offset 18
  std::string error;
  EXPECT_FALSE(ch10read::decode_fti_block(block, &error).has_value());
  EXPECT_EQ(error, "FTI block version 1: this reader decodes version 3 only (docs/fti-output.md)");
  block[19] = 2;
  for (std::size_t bytes : {std::size_t{152}, std::size_t{166}}) {
    block.resize(bytes);
    EXPECT_FALSE(ch10read::decode_fti_block(block, &error).has_value());
    EXPECT_EQ(error,
              "FTI block version 2: this reader decodes version 3 only (docs/fti-output.md)");
  }
  block[19] = 3;
  block.resize(152);
  EXPECT_FALSE(ch10read::decode_fti_block(block, &error).has_value());
  EXPECT_EQ(error, "FTI block version 3 of 152 bytes, needs 166");
  block.resize(166);
  const auto b = ch10read::decode_fti_block(block, &error);
  ASSERT_TRUE(b.has_value());
  EXPECT_EQ(b->version, 3);
}

// Reproducer of the Message F0 over-read (issue 11), minimised from the fuzz_ch10_reader seed
// tests/host/fuzz/seeds/ch10_reader/f0_odd_length_message.ch10: one F0 packet whose CSDW counts
// 2 messages, the first of odd length 1 at the very end of the data, without its filler byte.
// The old decoder stepped `at` past the data and read the second header out of bounds (ASan:
// heap-buffer-overflow in decode_message_f0).
TEST(Chapter10Reader, OddLengthMessageAtTheEndIsRefusedNotReadPast) {
  std::vector<std::uint8_t> file = {
      0x25, 0xEB, 0x02, 0x00,              // sync, channel 2
      44,   0,    0,    0,                 // packet length
      17,   0,    0,    0,                 // data length: CSDW + one 12-byte header + 1 byte
      0x06, 0x00, 0x00, 0x30,              // version, sequence, flags (no checksum), Message F0
      0,    0,    0,    0,    0, 0,        // relative time counter
      0,    0,                             // header checksum (below)
      2,    0,    0,    0,                 // CSDW: 2 messages
      0,    0,    0,    0,    0, 0, 0, 0,  // intra-packet time
      1,    0,    0,    0,                 // intra-packet header: length 1
      0xAB,                                // the message; its filler byte and message 2 are missing
      0,    0,    0};                      // packet filler to a multiple of 4
  std::uint32_t sum = 0;
  for (std::size_t i = 0; i < 22; i += 2)
    sum += static_cast<std::uint32_t>(file[i] | (file[i + 1] << 8));
  file[22] = static_cast<std::uint8_t>(sum);
  file[23] = static_cast<std::uint8_t>(sum >> 8);
  const ch10read::File f = ch10read::parse(file);
  ASSERT_EQ(f.packets.size(), 1u) << f.stop_reason;
  std::string error;
  EXPECT_FALSE(ch10read::decode_message_f0(f.packets[0], &error).has_value());
  EXPECT_EQ(error, "message filler byte past the data");
}

}  // namespace
}  // namespace storetrack::output
