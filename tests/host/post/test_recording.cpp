// read_recording (host/post): the files of one host run written by the Chapter 10 writer, read
// back through the independent reader; every refusal names the file.
#include <gtest/gtest.h>

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <filesystem>
#include <fstream>
#include <random>
#include <stdexcept>
#include <tuple>

#include "fti_sample_factory.hpp"
#include "recording.hpp"
#include "reprocessed_recording.hpp"
#include "scratch_files.hpp"
#include "storetrack/output/chapter10_writer.hpp"
#include "storetrack/output/fti_parameter_block.hpp"

namespace storetrack::post {
namespace {

namespace fs = std::filesystem;
using output::RecordedInputKind;

constexpr std::int64_t kT0Tai = (1'803'902'400LL + 37) * 1'000'000'000LL;
constexpr int kExposures = 40, kObservationsPerExposure = 8;

using test::bytes_of;
using test::fresh_dir;

output::Chapter10Config config(bool raw, bool inputs, const std::string& calibration = "{}") {
  output::Chapter10Config cfg;
  cfg.sync = output::Chapter10Sync::kNone;
  cfg.existing = output::Chapter10Existing::kRefuse;
  cfg.raw_observations = raw;
  if (inputs)
    cfg.inputs = {{RecordedInputKind::kCalibration, "rig.json", bytes_of(calibration)},
                  {RecordedInputKind::kCommandLine, "argv", bytes_of(std::string("host\0", 5))}};
  return cfg;
}

// Fault injection (Chapter10FileOps): the writes numbered in g_fail_writes fail once (a full
// disk), so the writer goes on in a continuation file.
std::vector<int> g_fail_writes;
int g_writes = 0;
ssize_t failing_write(int fd, const void* data, std::size_t size) {
  if (std::find(g_fail_writes.begin(), g_fail_writes.end(), ++g_writes) != g_fail_writes.end()) {
    errno = ENOSPC;
    return -1;
  }
  return ::write(fd, data, size);
}

// Observations (their bytes need not decode here), then the exposure's sample, as the host
// writes them; returns the samples' blocks as the host encodes them. `files`: the files written.
std::vector<std::vector<std::uint8_t>> write_run(const std::string& path,
                                                 const output::Chapter10Config& cfg,
                                                 std::vector<std::string>* files = nullptr) {
  output::Chapter10Writer w;
  if (files) {
    output::Chapter10FileOps ops = output::posix_chapter10_file_ops();
    ops.write = failing_write;
    w.set_file_ops(ops);
    g_writes = 0;
  }
  EXPECT_EQ(w.open(path, cfg), 0);
  std::mt19937_64 rng(5);
  std::vector<std::vector<std::uint8_t>> blocks;
  for (int k = 0; k < kExposures; ++k) {
    for (int j = 0; cfg.raw_observations && j < kObservationsPerExposure; ++j) {
      msg::RawObservation r{};
      const int n = k * kObservationsPerExposure + j;
      r.arrival_tai_ns = kT0Tai + n * 312'500LL;
      r.host_mono_ns = 7'000'000'000LL + n;
      r.flags = msg::raw_observation_flags::kAccepted;
      r.unit_id = static_cast<std::uint8_t>(n % 2);  // fields a copy must keep, varied
      r.camera_id = static_cast<std::uint8_t>(n % 4);
      r.source_address = 0x7F000001u + static_cast<std::uint32_t>(n % 3);
      r.source_port = static_cast<std::uint16_t>(40000 + n % 5);
      const std::vector<std::uint8_t> bytes(1 + n % 50, static_cast<std::uint8_t>(n));
      r.message_bytes = static_cast<std::uint16_t>(bytes.size());
      r.received_bytes = r.message_bytes;
      const int rc = w.write_raw(r, bytes);
      EXPECT_TRUE(rc == 0 || files) << rc;  // injected failures: written to the next file
    }
    const msg::FtiSample s =
        output::testing::make_sample(static_cast<std::uint32_t>(k), kT0Tai, rng);
    const int rc = w.write(s);
    EXPECT_TRUE(rc == 0 || files) << rc;
    std::vector<std::uint8_t> block(output::kFtiParameterBlockBytes);
    output::encode_fti_parameter_block(s, block);
    blocks.push_back(std::move(block));
  }
  EXPECT_EQ(w.close(), 0);
  if (files) *files = w.files();
  return blocks;
}

// The message of `read_recording(paths)`'s refusal ("" when it reads).
std::string refusal(const std::vector<std::string>& paths) {
  try {
    read_recording(paths);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

TEST(PostRecording, ReadsRecordsSamplesAndInputsInOrder) {
  const fs::path dir = fresh_dir("st_post_rec");
  const std::string path = (dir / "out.ch10").string();
  const auto blocks = write_run(path, config(true, true));
  const Recording r = read_recording({path});
  EXPECT_TRUE(r.torn.empty());
  ASSERT_EQ(r.records.size(), static_cast<std::size_t>(kExposures * kObservationsPerExposure));
  for (std::size_t i = 0; i < r.records.size(); ++i)
    EXPECT_EQ(r.records[i].host_mono_ns, 7'000'000'000LL + static_cast<std::int64_t>(i));
  ASSERT_EQ(r.samples.size(), blocks.size());
  for (std::size_t i = 0; i < blocks.size(); ++i)
    EXPECT_EQ(r.samples[i].block, blocks[i]) << "sample " << i;
  ASSERT_NE(find_input(r, static_cast<int>(RecordedInputKind::kCommandLine)), nullptr);
  EXPECT_EQ(find_input(r, static_cast<int>(RecordedInputKind::kCalibration))->bytes,
            bytes_of("{}"));
  fs::remove_all(dir);
}

TEST(PostRecording, RefusesARecordingWithoutTheRawChannel) {
  const fs::path dir = fresh_dir("st_post_noraw");
  const std::string path = (dir / "old.ch10").string();
  write_run(path, config(false, true));
  const std::string why = refusal({path});
  EXPECT_NE(why.find(path + ": no raw observation channel"), std::string::npos) << why;
  fs::remove_all(dir);
}

TEST(PostRecording, RefusesARecordingWithoutInputs) {
  const fs::path dir = fresh_dir("st_post_noinputs");
  const std::string path = (dir / "bare.ch10").string();
  write_run(path, config(true, false));
  const std::string why = refusal({path});
  EXPECT_NE(why.find(path + ": no recorded inputs"), std::string::npos) << why;
  fs::remove_all(dir);
}

TEST(PostRecording, RefusesAnUnreadableFileAndFilesOfAnotherRun) {
  const fs::path dir = fresh_dir("st_post_other");
  const std::string missing = (dir / "missing.ch10").string();
  EXPECT_NE(refusal({missing}).find(missing), std::string::npos) << refusal({missing});
  const std::string a = (dir / "a.ch10").string(), b = (dir / "b.ch10").string();
  write_run(a, config(true, true, "{\"rig\": 1}"));
  write_run(b, config(true, true, "{\"rig\": 2}"));
  const std::string why = refusal({a, b});
  EXPECT_NE(why.find(b + ": its recorded inputs differ from " + a), std::string::npos) << why;
  fs::remove_all(dir);
}

// A crash cuts the file inside its last packet: what comes before it is read, and said.
TEST(PostRecording, ReadsATornFileToItsLastWholePacket) {
  const fs::path dir = fresh_dir("st_post_torn");
  const std::string whole = (dir / "whole.ch10").string(), torn = (dir / "torn.ch10").string();
  write_run(whole, config(true, true));
  const auto size = fs::file_size(whole);
  fs::copy_file(whole, torn);
  fs::resize_file(torn, size - 7);
  const Recording full = read_recording({whole});
  const Recording cut = read_recording({torn});
  ASSERT_EQ(cut.torn.size(), 1u);
  EXPECT_EQ(cut.torn[0].rfind(torn + ": ", 0), 0u) << cut.torn[0];
  EXPECT_NE(cut.torn[0].find("ends inside"), std::string::npos) << cut.torn[0];
  // Some records or samples lost with the last packet; the rest exactly the whole file's first.
  EXPECT_LT(cut.records.size() + cut.samples.size(), full.records.size() + full.samples.size());
  ASSERT_LE(cut.records.size(), full.records.size());
  for (std::size_t i = 0; i < cut.records.size(); ++i)
    EXPECT_EQ(cut.records[i].bytes, full.records[i].bytes) << "record " << i;
  ASSERT_LE(cut.samples.size(), full.samples.size());
  for (std::size_t i = 0; i < cut.samples.size(); ++i)
    EXPECT_EQ(cut.samples[i].block, full.samples[i].block) << "sample " << i;
  fs::remove_all(dir);
}

// One run in three files (two failed writes): read in order, they are the run; the middle one
// missing, or the files out of order, or two runs with the same inputs, are refused, naming the
// file and the packet.
TEST(PostRecording, RefusesAMissingOrMisplacedContinuationFile) {
  const fs::path dir = fresh_dir("st_post_cont");
  std::vector<std::string> f;
  g_fail_writes = {7, 14};
  write_run((dir / "out.ch10").string(), config(true, true), &f);
  g_fail_writes.clear();
  ASSERT_EQ(f.size(), 3u);
  const Recording all = read_recording(f);
  ASSERT_EQ(all.records.size(), static_cast<std::size_t>(kExposures * kObservationsPerExposure));
  for (std::size_t i = 0; i < all.records.size(); ++i)  // each once, in order
    ASSERT_EQ(all.records[i].host_mono_ns, 7'000'000'000LL + static_cast<std::int64_t>(i));
  ASSERT_GT(read_recording({f[1]}).records.size(), 0u);  // the middle file holds records

  const std::string missing = refusal({f[0], f[2]});
  EXPECT_EQ(missing.rfind(f[2] + ": its first raw channel packet (offset ", 0), 0u) << missing;
  EXPECT_NE(missing.find("the last of " + f[0]), std::string::npos) << missing;
  EXPECT_NE(missing.find("a continuation file missing"), std::string::npos) << missing;

  const std::string swapped = refusal({f[1], f[0], f[2]});
  EXPECT_EQ(swapped.rfind(f[0] + ": its first raw record (packet at offset ", 0), 0u) << swapped;
  EXPECT_NE(swapped.find("not in the order the host wrote them"), std::string::npos) << swapped;

  // Two runs of the same inputs: the second starts its loop time and sequence numbers again.
  const std::string again = (dir / "again.ch10").string();
  write_run(again, config(true, true));
  const std::string two = refusal({f[0], f[1], f[2], again});
  EXPECT_EQ(two.rfind(again + ": its first raw", 0), 0u) << two;
  fs::remove_all(dir);
}

// Raw packets missing between two consecutive files (the host could not write them: the
// setup records are consecutive): replayed, and named in `gaps`. Made by cutting the second
// file's first raw packet out of it.
TEST(PostRecording, NamesRawPacketsMissingBetweenConsecutiveFiles) {
  const fs::path dir = fresh_dir("st_post_gap");
  std::vector<std::string> f;
  g_fail_writes = {7};
  write_run((dir / "out.ch10").string(), config(true, true), &f);
  g_fail_writes.clear();
  ASSERT_EQ(f.size(), 2u);
  const ch10read::File second = ch10read::read_file(f[1]);
  const int raw = ch10read::raw_channel_id(second);
  const auto first_raw = std::find_if(second.packets.begin(), second.packets.end(),
                                      [&](const auto& p) { return p.channel_id == raw; });
  ASSERT_NE(first_raw, second.packets.end());
  std::vector<char> bytes(fs::file_size(f[1]));
  std::ifstream(f[1], std::ios::binary)
      .read(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  const auto at = bytes.begin() + static_cast<std::ptrdiff_t>(first_raw->file_offset);
  bytes.erase(at, at + first_raw->packet_length);
  std::ofstream(f[1], std::ios::binary | std::ios::trunc)
      .write(bytes.data(), static_cast<std::streamsize>(bytes.size()));

  const Recording r = read_recording(f);
  ASSERT_EQ(r.integrity.size(), 2u);  // the first file and its continuation (--report)
  EXPECT_EQ(r.integrity[1].file, f[1]);
  ASSERT_EQ(r.gaps.size(), 1u);
  EXPECT_EQ(r.gaps[0].rfind(f[1] + ": its first raw channel packet (offset ", 0), 0u) << r.gaps[0];
  EXPECT_NE(r.gaps[0].find("1 (mod 256) raw packet(s) missing"), std::string::npos) << r.gaps[0];
  EXPECT_NE(r.gaps[0].find("packets the host could not write"), std::string::npos) << r.gaps[0];
  EXPECT_LT(r.records.size(), static_cast<std::size_t>(kExposures * kObservationsPerExposure));
  fs::remove_all(dir);
}

// The file as bytes, changed by `edit`, written back.
template <class Edit>
void edit_file(const std::string& path, Edit edit) {
  std::vector<char> bytes(fs::file_size(path));
  std::ifstream(path, std::ios::binary)
      .read(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  edit(bytes);
  std::ofstream(path, std::ios::binary | std::ios::trunc)
      .write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// The report's integrity counts (storetrack-post --report) equal the faults injected into a
// whole file: a torn last packet, a raw packet cut out of the middle, a header checksum broken.
TEST(PostRecording, IntegrityCountsTheInjectedFaults) {
  const fs::path dir = fresh_dir("st_post_integrity");
  const std::string whole = (dir / "whole.ch10").string();
  write_run(whole, config(true, true));
  const ch10read::File parsed = ch10read::read_file(whole);
  const FileIntegrity clean = read_recording({whole}).integrity.at(0);
  EXPECT_FALSE(clean.torn);
  EXPECT_EQ(clean.packets, parsed.packets.size());
  EXPECT_EQ(clean.bytes_in_whole_packets, clean.file_bytes);
  EXPECT_EQ(clean.header_checksum_errors + clean.data_checksum_errors, 0u);
  EXPECT_EQ(clean.sequence_gap_packets, 0u);

  const std::string torn = (dir / "torn.ch10").string();
  fs::copy_file(whole, torn);
  fs::resize_file(torn, fs::file_size(whole) - 7);
  const FileIntegrity cut = read_recording({torn}).integrity.at(0);
  EXPECT_TRUE(cut.torn);
  EXPECT_EQ(cut.file_bytes, fs::file_size(whole) - 7);
  EXPECT_EQ(cut.packets, parsed.packets.size() - 1);
  EXPECT_EQ(cut.bytes_in_whole_packets, parsed.packets.back().file_offset);

  // One raw packet of the middle cut out: one packet missing from its channel's sequence.
  const int raw = ch10read::raw_channel_id(parsed);
  std::vector<const ch10read::Packet*> raws;
  for (const ch10read::Packet& p : parsed.packets)
    if (p.channel_id == raw) raws.push_back(&p);
  ASSERT_GE(raws.size(), 3u);
  const ch10read::Packet& middle = *raws[raws.size() / 2];
  const std::string gapped = (dir / "gapped.ch10").string();
  fs::copy_file(whole, gapped);
  edit_file(gapped, [&](std::vector<char>& b) {
    const auto at = b.begin() + static_cast<std::ptrdiff_t>(middle.file_offset);
    b.erase(at, at + middle.packet_length);
  });
  EXPECT_EQ(read_recording({gapped}).integrity.at(0).sequence_gap_packets, 1u);

  // A header checksum broken: the reader stops there, and says where.
  const std::string crc = (dir / "crc.ch10").string();
  fs::copy_file(whole, crc);
  edit_file(crc, [&](std::vector<char>& b) { b[middle.file_offset + 22] ^= 0x5a; });
  const FileIntegrity broken = read_recording({crc}).integrity.at(0);
  EXPECT_TRUE(broken.torn);
  EXPECT_EQ(broken.stop_reason,
            "header checksum mismatch at offset " + std::to_string(middle.file_offset));
  EXPECT_EQ(broken.bytes_in_whole_packets, middle.file_offset);
  fs::remove_all(dir);
}

// storetrack-post --output-ch10's writer (reprocessed_recording): a source run copied record by
// record with its samples, a write failing mid-way (a full disk): the new recording goes on in
// out.001.ch10 as the host's does, and the two files read back as one run holding every raw
// record (each field as the source's) and every sample's block, in order.
TEST(PostRecording, AReprocessedRecordingContinuesInANumberedFileAndReadsBackWhole) {
  const fs::path dir = fresh_dir("st_post_reprocessed");
  const std::string source_path = (dir / "source.ch10").string();
  const std::vector<std::vector<std::uint8_t>> blocks = write_run(source_path, config(true, true));
  const Recording source = read_recording({source_path});
  std::mt19937_64 rng(5);  // write_run's samples, again
  std::vector<msg::FtiSample> samples;
  for (int k = 0; k < kExposures; ++k)
    samples.push_back(output::testing::make_sample(static_cast<std::uint32_t>(k), kT0Tai, rng));

  ReprocessedRecording out;
  output::Chapter10FileOps ops = output::posix_chapter10_file_ops();
  ops.write = failing_write;
  out.set_file_ops(ops);
  g_writes = 0;
  g_fail_writes = {9};
  output::Chapter10Config cfg = config(true, true);
  cfg.comments = {"reprocessed from 'source.ch10'"};
  ASSERT_EQ(out.open((dir / "new.ch10").string(), cfg), 0);
  std::vector<msg::FtiSample> written;  // as the replay's list grows
  for (std::size_t i = 0; i < source.records.size(); ++i) {
    out.copy(source.records[i]);
    if ((i + 1) % kObservationsPerExposure == 0) written.push_back(samples[written.size()]);
    out.record_new(written);
  }
  g_fail_writes.clear();
  EXPECT_EQ(out.close(), 0);
  EXPECT_EQ(out.writer().counters().continuation_files, 1u);
  ASSERT_EQ(out.writer().files(), (std::vector<std::string>{(dir / "new.ch10").string(),
                                                            (dir / "new.001.ch10").string()}));

  const Recording copy = read_recording(out.writer().files());
  ASSERT_EQ(copy.records.size(), source.records.size());
  for (std::size_t i = 0; i < copy.records.size(); ++i) {
    const ch10read::RawObservation &a = copy.records[i], &b = source.records[i];
    EXPECT_EQ(std::tie(a.arrival_tai_ns, a.host_mono_ns, a.source_kind, a.source_address,
                       a.source_port, a.unit_id, a.camera_id, a.flags, a.decode_error,
                       a.received_bytes, a.bytes, a.data_error, a.subchannel),
              std::tie(b.arrival_tai_ns, b.host_mono_ns, b.source_kind, b.source_address,
                       b.source_port, b.unit_id, b.camera_id, b.flags, b.decode_error,
                       b.received_bytes, b.bytes, b.data_error, b.subchannel))
        << "record " << i;
  }
  ASSERT_EQ(copy.samples.size(), blocks.size());
  for (std::size_t k = 0; k < blocks.size(); ++k)
    EXPECT_EQ(copy.samples[k].block, blocks[k]) << "sample " << k;
  fs::remove_all(dir);
}

// The host command line storetrack-post records with a substitute: the option's value replaced
// where given (either spelling), appended where the live run had none.
TEST(PostRecording, CommandLineNamesTheSubstitute) {
  using V = std::vector<std::string>;
  const V given{"host", "--calibration", "old.json", "--udp-port", "9"};
  EXPECT_EQ(command_line_with(given, "--calibration", "new.json"),
            (V{"host", "--calibration", "new.json", "--udp-port", "9"}));
  EXPECT_EQ(command_line_with({"host", "--config=a.json"}, "--config", "b.json"),
            (V{"host", "--config=b.json"}));
  EXPECT_EQ(command_line_with(given, "--config", "c.json"),
            (V{"host", "--calibration", "old.json", "--udp-port", "9", "--config", "c.json"}));
}

}  // namespace
}  // namespace storetrack::post
