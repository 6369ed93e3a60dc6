// The raw channel (every observation message as received, RawObservation records in Message
// Data F0 packets, channel 3) and the inputs channel (RecordedInput records in Computer-Generated
// F0 packets, channel 4) of the Chapter 10 writer, read back with the INDEPENDENT reader
// (storetrack::ch10read): bytes as written, SHA-256 equal to the published FIPS 180-4 vectors
// (not computed here), the inputs at the start of every file (continuation files too), and
// every observation in exactly one file or counted as dropped.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cerrno>
#include <filesystem>
#include <random>

#include "fti_sample_factory.hpp"
#include "scratch_files.hpp"
#include "storetrack/output/chapter10_reader.hpp"
#include "storetrack/output/chapter10_writer.hpp"

namespace storetrack::output {
namespace {

namespace fs = std::filesystem;

constexpr std::int64_t kUtc0 = 1'803'902'400;  // 2027-03-01 12:00:00 UTC
constexpr std::int64_t kT0Tai = (kUtc0 + 37) * 1'000'000'000LL + 600'000'000;

// Published SHA-256 values (FIPS 180-4 examples; FIPS 180-2 appendix B.3 for a million 'a').
constexpr const char* kShaAbc = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad";
constexpr const char* kShaEmpty =
    "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855";
constexpr const char* kShaMillionA =
    "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0";
constexpr const char* kSha448 = "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1";
constexpr const char* k448Bits = "abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq";

using test::bytes_of;
using test::fresh_dir;

std::string hex(const std::array<std::uint8_t, 32>& d) {
  std::string s;
  char b[3];
  for (auto x : d) {
    std::snprintf(b, sizeof b, "%02x", x);
    s += b;
  }
  return s;
}

// Inputs with known digests; the million-'a' file is longer than one packet's chunk.
std::vector<RecordedInputFile> test_inputs() {
  return {{RecordedInputKind::kCalibration, "rig.json", bytes_of("abc")},
          {RecordedInputKind::kPylonSurvey, "pylon.json", {}},
          {RecordedInputKind::kStoreSurvey, "store.json", bytes_of(std::string(1'000'000, 'a'))},
          {RecordedInputKind::kHostConfig, "host.json", bytes_of(k448Bits)}};
}
const char* expected_sha(int kind) {
  switch (kind) {
    case 0:
      return kShaAbc;
    case 1:
      return kShaEmpty;
    case 2:
      return kShaMillionA;
    default:
      return kSha448;
  }
}

struct Observation {
  msg::RawObservation record{};
  std::vector<std::uint8_t> bytes;
};

// Observations as a receiver would record them: lengths 1..600 (odd ones need the filler byte),
// some refused, one truncated, UDP and CAN, arrival a little after the sample's exposure.
std::vector<Observation> observations(int n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::vector<Observation> out;
  for (int k = 0; k < n; ++k) {
    Observation o;
    const std::size_t len = 1 + rng() % 600;
    o.bytes.resize(len);
    for (auto& b : o.bytes)
      b = static_cast<std::uint8_t>(rng());
    auto& r = o.record;
    r.source_kind = static_cast<std::uint8_t>(k % 5 == 0 ? 1 : 0);
    r.arrival_tai_ns = kT0Tai + static_cast<std::int64_t>(k) * 312'500 + 1'700'000;
    r.source_address = 0x7F000001u + static_cast<std::uint32_t>(k % 3);
    r.source_port = static_cast<std::uint16_t>(40000 + k % 7);
    r.unit_id = static_cast<std::uint8_t>(k % 4);
    r.camera_id = static_cast<std::uint8_t>(k % 8);
    r.flags = k % 11 == 3 ? 0 : msg::raw_observation_flags::kAccepted;
    if (k == 17) r.flags |= msg::raw_observation_flags::kTruncated;
    r.decode_error = static_cast<std::uint8_t>(k % 11 == 3 ? 4 : 0);
    r.received_bytes = static_cast<std::uint32_t>(k == 17 ? 3000 : len);
    // Past 2^32 (all eight bytes carry) and not the arrival time (its own field).
    r.host_mono_ns = 5'000'000'007 + static_cast<std::int64_t>(k) * 312'501;
    r.message_bytes = static_cast<std::uint16_t>(len);
    out.push_back(std::move(o));
  }
  return out;
}

Chapter10Config raw_config() {
  Chapter10Config cfg;
  cfg.max_messages_per_packet = 10;
  cfg.sync = Chapter10Sync::kNone;
  cfg.raw_observations = true;
  cfg.max_raw_messages_per_packet = 64;
  cfg.inputs = test_inputs();
  return cfg;
}

// Samples at 400 Hz with 8 observations each, observations first (they arrive before the
// exposure is released).
void write_interleaved(Chapter10Writer& w, int exposures, const std::vector<Observation>& obs) {
  std::mt19937_64 rng(3);
  for (int k = 0; k < exposures; ++k) {
    for (int j = 0; j < 8; ++j) {
      const auto& o = obs[static_cast<std::size_t>(8 * k + j)];
      w.write_raw(o.record, o.bytes);
    }
    w.write(testing::make_sample(static_cast<std::uint32_t>(k), kT0Tai, rng));
  }
}

void expect_same(const ch10read::RawObservation& got, const Observation& want) {
  const auto& r = want.record;
  EXPECT_EQ(got.version, 2);
  EXPECT_EQ(got.bytes, want.bytes);
  EXPECT_EQ(got.host_mono_ns, r.host_mono_ns);
  EXPECT_EQ(got.source_kind, r.source_kind);
  EXPECT_EQ(got.arrival_tai_ns, r.arrival_tai_ns);
  EXPECT_EQ(got.source_address, r.source_address);
  EXPECT_EQ(got.source_port, r.source_port);
  EXPECT_EQ(got.unit_id, r.unit_id);
  EXPECT_EQ(got.camera_id, r.camera_id);
  EXPECT_EQ(got.flags, r.flags);
  EXPECT_EQ(got.decode_error, r.decode_error);
  EXPECT_EQ(got.received_bytes, r.received_bytes);
  EXPECT_EQ(got.subchannel, r.unit_id);
  EXPECT_EQ(got.data_error, (r.flags & msg::raw_observation_flags::kAccepted) == 0);
  EXPECT_EQ(got.format_error, (r.flags & msg::raw_observation_flags::kTruncated) != 0);
}

// The file's inputs are the test inputs, whole, with the published digests.
void expect_inputs(const ch10read::File& f, const std::string& where) {
  std::string error;
  const auto inputs = ch10read::recorded_inputs(f, &error);
  EXPECT_TRUE(error.empty()) << where << ": " << error;
  const auto want = test_inputs();
  ASSERT_EQ(inputs.size(), want.size()) << where;
  for (std::size_t i = 0; i < want.size(); ++i) {
    EXPECT_EQ(inputs[i].channel_id, 4) << where;
    EXPECT_EQ(inputs[i].kind, static_cast<int>(want[i].kind)) << where;
    EXPECT_EQ(inputs[i].name, want[i].name) << where;
    EXPECT_TRUE(inputs[i].complete) << where << " " << want[i].name;
    EXPECT_EQ(inputs[i].bytes, want[i].bytes) << where << " " << want[i].name;
    EXPECT_EQ(hex(inputs[i].sha256), expected_sha(inputs[i].kind)) << where << " " << want[i].name;
  }
  // They follow the setup record, before any time or data packet.
  ASSERT_GE(f.packets.size(), 2u);
  EXPECT_EQ(f.packets[0].data_type, 0x01);
  EXPECT_EQ(f.packets[1].data_type, 0x00);
}

// Every packet whole and checked; a time packet precedes every message packet.
void expect_valid_file(const ch10read::File& f, const std::string& where) {
  EXPECT_TRUE(f.stop_reason.empty()) << where << ": " << f.stop_reason;
  bool time_seen = false;
  for (const auto& p : f.packets) {
    EXPECT_TRUE(p.header_checksum_ok && p.data_checksum_ok) << where << " at " << p.file_offset;
    if (p.data_type == 0x11) time_seen = true;
    if (p.data_type == 0x30) {
      EXPECT_TRUE(time_seen) << where << ": data before any time packet";
    }
  }
}

TEST(Chapter10Raw, RoundTripOfObservationsAndInputs) {
  const fs::path dir = fresh_dir("st_ch10_raw");
  const int exposures = 400;
  const auto obs = observations(8 * exposures, 11);
  Chapter10Writer w;
  ASSERT_EQ(w.open((dir / "out.ch10").string(), raw_config()), 0);
  write_interleaved(w, exposures, obs);
  ASSERT_EQ(w.close(), 0);
  const ch10read::File f = ch10read::read_file((dir / "out.ch10").string());
  expect_valid_file(f, "out.ch10");
  expect_inputs(f, "out.ch10");
  EXPECT_EQ(ch10read::raw_channel_id(f), 3);
  std::string error;
  const auto got = ch10read::raw_observations(f, &error);
  EXPECT_TRUE(error.empty()) << error;
  ASSERT_EQ(got.size(), obs.size());
  for (std::size_t i = 0; i < obs.size(); ++i)
    expect_same(got[i], obs[i]);
  // The time stamps map to the arrival times through the file's time packet (RTC at 10 MHz).
  std::optional<ch10read::TimeF1> t;
  std::uint64_t t_rtc = 0;
  for (const auto& p : f.packets)
    if (!t && (t = ch10read::decode_time_f1(p))) t_rtc = p.relative_time_counter;
  ASSERT_TRUE(t);
  for (const auto& r : got) {
    const std::int64_t tai_ns =
        (t->utc_epoch_seconds + 37) * 1'000'000'000LL +
        (static_cast<std::int64_t>(r.intra_packet_time) - static_cast<std::int64_t>(t_rtc)) * 100;
    EXPECT_NEAR(static_cast<double>(tai_ns - r.arrival_tai_ns), 0.0, 100.0);
  }
  const Chapter10Counters& c = w.counters();
  EXPECT_EQ(c.raw_messages_written, obs.size());
  // The 8 observations before the first sample are held for its time base, then 64 a packet.
  EXPECT_EQ(c.raw_packets, 1 + (obs.size() - 8 + 63) / 64);
  std::uint64_t bytes = 0;
  for (const auto& o : obs)
    bytes += o.bytes.size();
  EXPECT_EQ(c.raw_bytes_written, bytes);
  EXPECT_EQ(c.raw_messages_dropped + c.raw_packets_dropped + c.raw_refused, 0u);
  EXPECT_EQ(c.messages_written, static_cast<std::uint64_t>(exposures));  // samples unchanged
  EXPECT_EQ(c.input_packets, 3u + 6u);  // the million bytes in 192 KiB chunks: 6 packets
  // TMATS describes the raw channel and names every input with its digest.
  const auto tmats = ch10read::decode_tmats(f.packets.front());
  ASSERT_TRUE(tmats);
  EXPECT_NE(tmats->find("R-1\\DSI-3:RAWOBS;"), std::string::npos);
  EXPECT_NE(tmats->find("R-1\\CDT-3:MSGIN;"), std::string::npos);
  EXPECT_NE(tmats->find("R-1\\N:3;"), std::string::npos);
  EXPECT_NE(tmats->find(std::string("'rig.json' 3 bytes sha256 ") + kShaAbc), std::string::npos);
  fs::remove_all(dir);
}

// Fault injection: the n-th write fails once.
int g_write_fail_at = 0, g_writes = 0;
ssize_t failing_write(int fd, const void* data, std::size_t size) {
  if (++g_writes == g_write_fail_at) {
    errno = ENOSPC;
    return -1;
  }
  return ::write(fd, data, size);
}

TEST(Chapter10Raw, ContinuationFilesStartWithTheInputsAndLoseNoObservation) {
  const fs::path dir = fresh_dir("st_ch10_raw_cont");
  const int exposures = 400;
  const auto obs = observations(8 * exposures, 12);
  for (int fail_at : {30, 57, 90}) {  // inside the run: a sample packet or a raw packet
    SCOPED_TRACE(fail_at);
    fs::remove_all(dir);
    fs::create_directories(dir);
    g_writes = 0;
    g_write_fail_at = fail_at;
    Chapter10Writer w;
    Chapter10FileOps ops = posix_chapter10_file_ops();
    ops.write = failing_write;
    w.set_file_ops(ops);
    ASSERT_EQ(w.open((dir / "out.ch10").string(), raw_config()), 0);
    write_interleaved(w, exposures, obs);
    w.close();
    ASSERT_EQ(w.files().size(), 2u);
    std::vector<ch10read::RawObservation> all;
    for (const auto& path : w.files()) {
      const ch10read::File f = ch10read::read_file(path);
      expect_valid_file(f, path);
      expect_inputs(f, path);
      const auto got = ch10read::raw_observations(f);
      all.insert(all.end(), got.begin(), got.end());
    }
    // The failed packet was retried at the start of the continuation file: nothing lost.
    EXPECT_EQ(w.counters().raw_messages_dropped, 0u);
    ASSERT_EQ(all.size(), obs.size());
    for (std::size_t i = 0; i < obs.size(); ++i)
      expect_same(all[i], obs[i]);
  }
  fs::remove_all(dir);
}

TEST(Chapter10Raw, ObservationsWithoutAnySampleSetTheTimeBaseThemselves) {
  const fs::path dir = fresh_dir("st_ch10_raw_only");
  const auto obs = observations(100, 13);
  Chapter10Config cfg = raw_config();
  cfg.max_held_raw_messages = 30;  // held until a sample would fix the time base, then written
  Chapter10Writer w;
  ASSERT_EQ(w.open((dir / "out.ch10").string(), cfg), 0);
  for (const auto& o : obs)
    ASSERT_EQ(w.write_raw(o.record, o.bytes), 0);
  ASSERT_EQ(w.close(), 0);
  const ch10read::File f = ch10read::read_file((dir / "out.ch10").string());
  expect_valid_file(f, "out.ch10");
  const auto got = ch10read::raw_observations(f);
  ASSERT_EQ(got.size(), obs.size());
  std::optional<ch10read::TimeF1> t;
  for (const auto& p : f.packets)
    if (!t) t = ch10read::decode_time_f1(p);
  ASSERT_TRUE(t);
  EXPECT_EQ(t->utc_epoch_seconds, kUtc0);  // the first arrival's UTC second
  for (std::size_t i = 0; i < obs.size(); ++i) {
    expect_same(got[i], obs[i]);
    EXPECT_EQ(static_cast<std::int64_t>(got[i].intra_packet_time) * 100,
              obs[i].record.arrival_tai_ns - (kUtc0 + 37) * 1'000'000'000LL);
  }
  fs::remove_all(dir);
}

TEST(Chapter10Raw, RawChannelOffRefusesAndIsNotDescribed) {
  const fs::path dir = fresh_dir("st_ch10_raw_off");
  Chapter10Config cfg = raw_config();
  cfg.raw_observations = false;
  cfg.inputs.clear();
  Chapter10Writer w;
  ASSERT_EQ(w.open((dir / "out.ch10").string(), cfg), 0);
  const auto obs = observations(3, 14);
  EXPECT_EQ(w.write_raw(obs[0].record, obs[0].bytes), -EINVAL);
  ASSERT_EQ(w.close(), 0);
  EXPECT_EQ(w.counters().raw_refused, 1u);
  const ch10read::File f = ch10read::read_file((dir / "out.ch10").string());
  EXPECT_EQ(ch10read::raw_channel_id(f), -1);
  std::string error;
  EXPECT_TRUE(ch10read::raw_observations(f, &error).empty());
  EXPECT_NE(error.find("no raw channel"), std::string::npos);
  EXPECT_TRUE(ch10read::recorded_inputs(f).empty());
  fs::remove_all(dir);
}

TEST(Chapter10Raw, SizeMismatchIsRefusedAndCounted) {
  const fs::path dir = fresh_dir("st_ch10_raw_size");
  Chapter10Writer w;
  Chapter10Config cfg = raw_config();
  cfg.inputs.clear();
  ASSERT_EQ(w.open((dir / "out.ch10").string(), cfg), 0);
  auto o = observations(1, 15)[0];
  o.record.message_bytes = static_cast<std::uint16_t>(o.bytes.size() + 1);
  EXPECT_EQ(w.write_raw(o.record, o.bytes), -EINVAL);
  std::vector<std::uint8_t> huge(msg::kRawObservationMaxTailBytes + 1, 0x55);
  o.record.message_bytes = static_cast<std::uint16_t>(huge.size());
  EXPECT_EQ(w.write_raw(o.record, huge), -EINVAL);
  EXPECT_EQ(w.counters().raw_refused, 2u);
  ASSERT_EQ(w.close(), 0);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace storetrack::output
