// A recording is never overwritten or left with partial bytes mid-file: the Chapter 10 writer
// under a restart on the same path, a real file-size limit (RLIMIT_FSIZE: a short write, then
// EFBIG), injected fdatasync / close / write faults, and a message count beyond the 16-bit CSDW.
// Every file it leaves is read back by the INDEPENDENT reader (storetrack::ch10read) to its end
// with no checksum error, and every sample is in exactly one file, in order, or counted as
// dropped.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
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

// A fresh directory per test: the numbered files land next to the requested one.
using test::fresh_dir;

Chapter10Config test_config(int per_packet) {
  Chapter10Config cfg;
  cfg.max_messages_per_packet = per_packet;
  cfg.sync = Chapter10Sync::kNone;
  return cfg;
}

std::vector<msg::FtiSample> samples(int n, std::uint64_t seed = 5) {
  std::mt19937_64 rng(seed);
  std::vector<msg::FtiSample> out;
  for (int k = 0; k < n; ++k)
    out.push_back(testing::make_sample(static_cast<std::uint32_t>(k), kT0Tai, rng));
  return out;
}

// A whole, valid file: parsed to its last byte, every checksum right, TMATS first. Returns the
// trigger sequence numbers of its messages in file order.
std::vector<std::uint32_t> read_whole_file(const fs::path& path) {
  const ch10read::File f = ch10read::read_file(path.string());
  EXPECT_TRUE(f.stop_reason.empty()) << path << ": " << f.stop_reason;
  EXPECT_FALSE(f.truncated) << path;
  EXPECT_EQ(f.bytes_in_whole_packets, fs::file_size(path)) << path;
  std::vector<std::uint32_t> seqs;
  if (f.packets.empty()) return seqs;
  EXPECT_EQ(f.packets.front().data_type, 0x01) << path << ": TMATS first";
  bool time_seen = false;
  for (const auto& p : f.packets) {
    EXPECT_TRUE(p.header_checksum_ok);
    EXPECT_TRUE(p.data_checksum_ok) << path << " packet at " << p.file_offset;
    if (p.data_type == 0x11) time_seen = true;
    if (p.data_type != 0x30) continue;
    // Absolute time of every message comes from a time packet earlier in the SAME file.
    EXPECT_TRUE(time_seen) << path << ": message packet before any time packet";
    std::string error;
    const auto msgs = ch10read::decode_message_f0(p, &error);
    EXPECT_TRUE(msgs) << error;
    if (!msgs) continue;
    for (const auto& m : *msgs)
      seqs.push_back(ch10read::decode_fti_block(m.bytes)->trigger_seq);
  }
  return seqs;
}

// The requested file and its numbered successors, in number order, as far as they exist.
std::vector<fs::path> recording_files(const fs::path& first) {
  std::vector<fs::path> files;
  if (fs::exists(first)) files.push_back(first);
  for (int n = 1; n <= 999; ++n) {
    const fs::path p = first.parent_path() / (first.stem().string() + "." +
                                              (n < 10    ? "00"
                                               : n < 100 ? "0"
                                                         : "") +
                                              std::to_string(n) + first.extension().string());
    if (!fs::exists(p)) break;
    files.push_back(p);
  }
  return files;
}

std::vector<std::uint32_t> seqs_of(const std::vector<msg::FtiSample>& s) {
  std::vector<std::uint32_t> out;
  for (const auto& x : s)
    out.push_back(x.trigger_seq);
  return out;
}

TEST(Chapter10Recording, RestartOnTheSamePathKeepsTheEarlierRecording) {
  const fs::path dir = fresh_dir("st_ch10_restart");
  const fs::path path = dir / "out.ch10";
  const auto first = samples(100, 1), second = samples(40, 2);
  {
    Chapter10Writer w;
    ASSERT_EQ(w.open(path.string(), test_config(10)), 0);
    for (const auto& s : first)
      ASSERT_EQ(w.write(s), 0);
    ASSERT_EQ(w.close(), 0);
  }
  {  // the host restarted with the same --ch10
    Chapter10Writer w;
    ASSERT_EQ(w.open(path.string(), test_config(10)), 0);
    for (const auto& s : second)
      ASSERT_EQ(w.write(s), 0);
    ASSERT_EQ(w.close(), 0);
  }
  EXPECT_EQ(read_whole_file(path), seqs_of(first)) << "the first recording was overwritten";
  const auto files = recording_files(path);
  ASSERT_EQ(files.size(), 2u);
  EXPECT_EQ(files[1].filename(), "out.001.ch10");
  EXPECT_EQ(read_whole_file(files[1]), seqs_of(second));
  fs::remove_all(dir);
}

TEST(Chapter10Recording, NumberedFileIsReportedAndRefuseModeRefuses) {
  const fs::path dir = fresh_dir("st_ch10_refuse");
  const fs::path path = dir / "out.ch10";
  for (int run = 0; run < 3; ++run) {
    Chapter10Writer w;
    ASSERT_EQ(w.open(path.string(), test_config(10)), 0);
    ASSERT_EQ(w.files().size(), 1u);
    EXPECT_EQ(w.files()[0], run == 0 ? path.string() : numbered_chapter10_path(path.string(), run));
    EXPECT_EQ(w.counters().numbered_instead_of_existing, run == 0 ? 0u : 1u);
    EXPECT_EQ(w.close(), 0);
  }
  const auto size_before = fs::file_size(path);
  Chapter10Config refuse = test_config(10);
  refuse.existing = Chapter10Existing::kRefuse;
  Chapter10Writer w;
  EXPECT_EQ(w.open(path.string(), refuse), -EEXIST);
  EXPECT_EQ(w.write(samples(1)[0]), -EBADF);
  EXPECT_EQ(fs::file_size(path), size_before);
  EXPECT_EQ(numbered_chapter10_path("dir/run", 7), "dir/run.007");
  fs::remove_all(dir);
}

TEST(Chapter10Recording, FileSizeLimitCutsBackToTheLastWholePacketAndContinues) {
  // A real limit: RLIMIT_FSIZE in a child process with SIGXFSZ ignored. The packet that crosses
  // it is written short (up to the limit), its next write() fails with EFBIG.
  const fs::path dir = fresh_dir("st_ch10_fsize");
  const fs::path path = dir / "out.ch10";
  const auto all = samples(2000);
  constexpr rlim_t kLimit = 40'000;  // not a multiple of the 1 152-byte packets
  int pipefd[2];
  ASSERT_EQ(pipe(pipefd), 0);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    close(pipefd[0]);
    signal(SIGXFSZ, SIG_IGN);
    const rlimit lim{kLimit, kLimit};
    if (setrlimit(RLIMIT_FSIZE, &lim) != 0) _exit(3);
    Chapter10Writer w;
    if (w.open(path.string(), test_config(7)) != 0) _exit(4);
    for (const auto& s : all)
      w.write(s);
    w.close();
    const Chapter10Counters c = w.counters();
    (void)!write(pipefd[1], &c, sizeof c);
    _exit(0);
  }
  close(pipefd[1]);
  Chapter10Counters c{};
  const ssize_t got = read(pipefd[0], &c, sizeof c);
  close(pipefd[0]);
  int status = 0;
  waitpid(child, &status, 0);
  ASSERT_TRUE(WIFEXITED(status)) << "writer child killed (SIGXFSZ?)";
  ASSERT_EQ(WEXITSTATUS(status), 0);
  std::vector<std::uint32_t> recorded;
  const auto files = recording_files(path);
  for (const auto& f : files) {
    EXPECT_LE(fs::file_size(f), kLimit);
    const auto seqs = read_whole_file(f);
    recorded.insert(recorded.end(), seqs.begin(), seqs.end());
  }
  // Every sample in exactly one file, in order: the failed packet went into the next file.
  EXPECT_EQ(recorded, seqs_of(all));
  EXPECT_GE(files.size(), 8u);  // 2000 x 160 B of messages / 40 kB
  ASSERT_EQ(got, static_cast<ssize_t>(sizeof c));
  EXPECT_EQ(c.continuation_files, files.size() - 1);
  EXPECT_EQ(c.write_errors, files.size() - 1);
  EXPECT_EQ(c.truncations, files.size() - 1);
  EXPECT_EQ(c.messages_dropped, 0u);
  EXPECT_EQ(c.messages_written, all.size());
  fs::remove_all(dir);
}

// Fault injection: the n-th call of a system call fails (counting from 1), or every call from
// `from` on when `sticky`.
struct Faults {
  int write_fail_at = 0, write_short_at = 0, sync_fail_at = 0;
  bool close_fails = false, sticky_write = false;
  int writes = 0, syncs = 0, directory_syncs = 0;
};
Faults g_faults;

ssize_t faulty_write(int fd, const void* data, std::size_t size) {
  const int n = ++g_faults.writes;
  if (g_faults.write_short_at == n && size > 1) return ::write(fd, data, size / 2);
  if (g_faults.write_fail_at == n || (g_faults.sticky_write && n >= g_faults.write_fail_at)) {
    errno = ENOSPC;
    return -1;
  }
  return ::write(fd, data, size);
}
int faulty_fdatasync(int fd) {
  if (++g_faults.syncs == g_faults.sync_fail_at) {
    errno = EIO;
    return -1;
  }
  return ::fdatasync(fd);
}
int faulty_close(int fd) {
  ::close(fd);
  if (!g_faults.close_fails) return 0;
  errno = EIO;
  return -1;
}
int counting_fsync_directory(int fd) {
  struct stat st {};
  if (::fstat(fd, &st) == 0 && S_ISDIR(st.st_mode)) ++g_faults.directory_syncs;
  return ::fsync(fd);
}
Chapter10FileOps faulty_ops() {
  return {faulty_write, faulty_fdatasync, ::ftruncate, faulty_close, counting_fsync_directory};
}

struct Recorded {
  std::vector<std::string> files;
  Chapter10Counters counters;
  int close_rc = 0;
};
Recorded record(const fs::path& path, const std::vector<msg::FtiSample>& all, Faults faults,
                Chapter10Sync sync = Chapter10Sync::kNone) {
  g_faults = faults;
  Chapter10Writer w;
  w.set_file_ops(faulty_ops());
  Chapter10Config cfg = test_config(5);
  cfg.sync = sync;
  EXPECT_EQ(w.open(path.string(), cfg), 0);
  for (const auto& s : all)
    w.write(s);
  Recorded r;
  r.close_rc = w.close();
  r.files = w.files();
  r.counters = w.counters();
  return r;
}

TEST(Chapter10Recording, ShortWriteThenErrorLeavesNoPartialBytesMidFile) {
  const fs::path dir = fresh_dir("st_ch10_short");
  const auto all = samples(300);
  // Write 20 is cut short, its continuation write 21 fails: the file is cut back and the
  // packet goes to the continuation file.
  const Recorded r = record(dir / "out.ch10", all, {.write_fail_at = 21, .write_short_at = 20});
  ASSERT_EQ(r.files.size(), 2u);
  std::vector<std::uint32_t> recorded;
  for (const auto& f : r.files) {
    const auto seqs = read_whole_file(f);
    recorded.insert(recorded.end(), seqs.begin(), seqs.end());
  }
  EXPECT_EQ(recorded, seqs_of(all));
  EXPECT_EQ(r.counters.truncations, 1u);
  EXPECT_EQ(r.counters.write_errors, 1u);
  EXPECT_EQ(r.counters.messages_dropped, 0u);
  EXPECT_EQ(g_faults.directory_syncs, 2) << "the directory of each new file is fsynced";
  EXPECT_EQ(r.counters.directory_sync_errors, 0u);
  fs::remove_all(dir);
}

TEST(Chapter10Recording, FdatasyncErrorIsReportedAndTheRecordingMovesToANewFile) {
  const fs::path dir = fresh_dir("st_ch10_sync");
  const auto all = samples(300);
  const Recorded r =
      record(dir / "out.ch10", all, {.sync_fail_at = 12}, Chapter10Sync::kEveryPacket);
  EXPECT_EQ(r.counters.sync_errors, 1u);
  ASSERT_EQ(r.files.size(), 2u);  // the file whose data may not be on disk is not used further
  std::vector<std::uint32_t> recorded;
  for (const auto& f : r.files) {
    const auto seqs = read_whole_file(f);
    recorded.insert(recorded.end(), seqs.begin(), seqs.end());
  }
  EXPECT_EQ(recorded, seqs_of(all));  // the unsynced packet stays in the first file
  EXPECT_EQ(r.close_rc, 0);
  fs::remove_all(dir);
}

// UTC seconds of a file's time packets, in file order.
std::vector<std::int64_t> time_packet_seconds(const fs::path& path) {
  std::vector<std::int64_t> seconds;
  for (const auto& p : ch10read::read_file(path.string()).packets)
    if (p.data_type == 0x11)
      if (const auto t = ch10read::decode_time_f1(p)) seconds.push_back(t->utc_epoch_seconds);
  return seconds;
}

TEST(Chapter10Recording, ContinuationAtTheNextSecondsTimePacketStartsWithThatSecond) {
  // Samples from 12:00:00.6 at 400 Hz, 5 per packet: writes 1 TMATS, 2 time (12:00:00), 3-34
  // the 32 packets of that second's 160 samples; write 35, the time packet of 12:00:01, fails.
  // The continuation file must hold one time packet, 12:00:01, before its samples (before: it
  // repeated 12:00:00, a second with no sample in it, then 12:00:01).
  const fs::path dir = fresh_dir("st_ch10_time_order");
  const auto all = samples(300);
  const Recorded r = record(dir / "out.ch10", all, {.write_fail_at = 35});
  ASSERT_EQ(r.files.size(), 2u);
  EXPECT_EQ(time_packet_seconds(r.files[0]), std::vector<std::int64_t>{kUtc0});
  EXPECT_EQ(time_packet_seconds(r.files[1]), std::vector<std::int64_t>{kUtc0 + 1});
  std::vector<std::uint32_t> recorded;
  for (const auto& f : r.files) {
    const auto seqs = read_whole_file(f);
    recorded.insert(recorded.end(), seqs.begin(), seqs.end());
  }
  EXPECT_EQ(recorded, seqs_of(all));
  EXPECT_EQ(read_whole_file(r.files[0]).size(), 160u);
  fs::remove_all(dir);
}

TEST(Chapter10Recording, CloseErrorIsReported) {
  const fs::path dir = fresh_dir("st_ch10_close");
  const Recorded r = record(dir / "out.ch10", samples(50), {.close_fails = true});
  EXPECT_EQ(r.close_rc, -EIO);
  EXPECT_EQ(r.counters.close_errors, 1u);
  fs::remove_all(dir);
}

TEST(Chapter10Recording, LastingWriteFaultDropsCountedAndLeavesNoEmptyFiles) {
  // Every write from the 4th on fails (a full disk): the first file keeps its whole packets,
  // the samples after are counted as dropped, and the continuation tries (at most one failed
  // try per UTC second of samples) leave no empty files behind.
  const fs::path dir = fresh_dir("st_ch10_full");
  const auto all = samples(1000);  // 2.5 s of samples: UTC seconds 12:00:00 .. 12:00:03
  const Recorded r = record(dir / "out.ch10", all, {.write_fail_at = 4, .sticky_write = true});
  ASSERT_EQ(r.files.size(), 1u);
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 1);
  const auto seqs = read_whole_file(r.files[0]);
  EXPECT_EQ(r.counters.messages_written, seqs.size());
  EXPECT_EQ(r.counters.messages_written + r.counters.messages_dropped, all.size());
  EXPECT_LE(r.counters.continuation_files, 4u);
  EXPECT_GE(r.counters.messages_dropped, 990u);  // writes 1-3: TMATS, time, one 5-sample packet
  fs::remove_all(dir);
}

TEST(Chapter10Recording, OpenOnAFullDiskLeavesNoFileAndARestartFindsThePathFree) {
  // The disk is full when the host starts (or restarts: the fault campaign restarts a host that
  // exited): the file is created but its TMATS cannot be written. open() says so, and removes
  // the empty file it created, so three restarts leave no trail of empty numbered files (each
  // would be a "recording" without its TMATS; 999 restarts would use up every number) and the
  // requested path is free for the next open once the disk has room.
  const fs::path dir = fresh_dir("st_ch10_full_at_open");
  for (int restart = 0; restart < 3; ++restart) {
    g_faults = {.write_fail_at = 1, .sticky_write = true};
    Chapter10Writer w;
    w.set_file_ops(faulty_ops());
    EXPECT_EQ(w.open((dir / "out.ch10").string(), test_config(5)), -ENOSPC);
    EXPECT_EQ(w.write(samples(1)[0]), -EBADF) << "nothing is written after a failed open";
    EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 0)
        << "restart " << restart;
  }
  const Recorded r = record(dir / "out.ch10", samples(20), {});
  ASSERT_EQ(r.files.size(), 1u);
  EXPECT_EQ(fs::path(r.files[0]).filename(), "out.ch10");
  EXPECT_EQ(read_whole_file(r.files[0]), seqs_of(samples(20)));
  fs::remove_all(dir);
}

TEST(Chapter10Recording, MessagesPerPacketBoundedByTheCsdwCount) {
  // 70 000 messages asked per packet; the CSDW counts 16 bits (65 535): more would spill into
  // the packet-type bits 17-16 and make the packet unreadable.
  const fs::path dir = fresh_dir("st_ch10_csdw");
  const fs::path path = dir / "out.ch10";
  Chapter10Config cfg = test_config(70'000);
  cfg.max_packet_span_ns = 1'000'000'000;
  std::mt19937_64 rng(9);
  std::vector<msg::FtiSample> all;
  for (std::uint32_t k = 0; k < 70'001; ++k) {
    all.push_back(testing::make_sample(k, kT0Tai, rng));
    all.back().exposure_mid_tai_ns = kT0Tai + k;  // all in one UTC second: one packet if allowed
  }
  {
    Chapter10Writer w;
    ASSERT_EQ(w.open(path.string(), cfg), 0);
    for (const auto& s : all)
      w.write(s);
    ASSERT_EQ(w.close(), 0);
  }
  EXPECT_EQ(read_whole_file(path), seqs_of(all));
  fs::remove_all(dir);
}

ch10read::Packet message_packet(std::vector<std::uint8_t> data) {
  ch10read::Packet p;
  p.data_type = 0x30;
  p.data = std::move(data);
  p.data.shrink_to_fit();
  return p;
}
void put_message(std::vector<std::uint8_t>& d, std::uint16_t length, bool filler) {
  d.insert(d.end(), 8, 0);  // intra-packet time stamp
  d.push_back(static_cast<std::uint8_t>(length));
  d.push_back(static_cast<std::uint8_t>(length >> 8));
  d.push_back(1);  // subchannel 1
  d.push_back(0);
  d.insert(d.end(), length, 0xAB);
  if (filler && (length & 1)) d.push_back(0);
}

TEST(Chapter10Reader, OddLengthLastMessageWithoutFillerIsAnErrorNotAnOverread) {
  // CSDW says 2 messages; the first has odd length 1 and the data ends without its filler byte.
  std::vector<std::uint8_t> d = {2, 0, 0, 0};
  put_message(d, 1, false);
  std::string error;
  EXPECT_FALSE(ch10read::decode_message_f0(message_packet(d), &error));
  EXPECT_EQ(error, "message filler byte past the data");
  // The same with the filler byte and a second message decodes.
  d = {2, 0, 0, 0};
  put_message(d, 1, true);
  put_message(d, 3, true);
  const auto msgs = ch10read::decode_message_f0(message_packet(d), &error);
  ASSERT_TRUE(msgs) << error;
  ASSERT_EQ(msgs->size(), 2u);
  EXPECT_EQ((*msgs)[1].bytes, std::vector<std::uint8_t>(3, 0xAB));
}

}  // namespace
}  // namespace storetrack::output
