// The RecordingWriter takes all file I/O off the real-time thread. Its disk is made to stall for
// real: the marks CSV is a FIFO whose reader does not read, so the writer thread blocks in
// write() once the pipe buffer is full. The real-time side (push) must then neither block nor
// grow without bound: exactly the queue's capacity is held, every further item is counted as
// dropped, and once the "disk" moves again every held item reaches every file.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <csignal>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>
#include <vector>

#include "recording_writer.hpp"
#include "scratch_files.hpp"
#include "stats.hpp"
#include "storetrack/output/chapter10_reader.hpp"

namespace storetrack::hostapp {
namespace {

namespace fs = std::filesystem;

using test::fresh_dir;

// One text line of n - 1 copies of c (built in place: GCC 12 at -O3 warns falsely,
// -Warray-bounds, on std::string(n, c) + "\n" once inlined into a larger caller).
std::string text_line(std::size_t n, char c) {
  std::string line(n, c);
  line.back() = '\n';
  return line;
}

RecordingItem item(std::uint32_t k) {
  RecordingItem it;
  it.sample.trigger_seq = k;
  it.sample.store_id = 1;
  it.sample.exposure_mid_tai_ns = 1'900'000'000'000'000'000LL + k * 2'500'000LL;
  it.marks_rows = text_line(1001, 'm');  // 1 kB per exposure: the pipe fills at 64
  return it;
}

TEST(RecordingWriter, StalledDiskNeitherBlocksNorGrowsTheRealTimeSide) {
  const fs::path dir = fresh_dir("st_recording_stall");
  const fs::path fifo = dir / "marks.csv";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const int reader = ::open(fifo.c_str(), O_RDONLY | O_NONBLOCK);  // opened, never read yet
  ASSERT_GE(reader, 0);
  constexpr std::size_t kCapacity = 100;
  RecordingWriter w(kCapacity);
  output::Chapter10Config ch10;
  ch10.sync = output::Chapter10Sync::kNone;
  ASSERT_EQ(w.open_ch10((dir / "out.ch10").string(), ch10), 0);
  ASSERT_EQ(w.open_marks_csv(fifo.string()), 0);
  w.start();
  constexpr std::uint32_t kItems = 5000;
  std::size_t accepted = 0;
  double worst_push_ms = 0;
  for (std::uint32_t k = 0; k < kItems; ++k) {
    const auto t0 = std::chrono::steady_clock::now();
    accepted += w.push(item(k)) ? 1 : 0;
    worst_push_ms = std::max(
        worst_push_ms,
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  // The writer thread took at most a pipe buffer (64 kB of 1 kB rows, plus the one item it is
  // blocked on, and an 8 kB stdio buffer) out of the queue, the queue holds its capacity, the rest
  // was dropped and counted.
  EXPECT_LE(accepted, kCapacity + 100);
  EXPECT_GE(accepted, kCapacity);
  EXPECT_LT(worst_push_ms, 50.0) << "push() blocked on the stalled disk";
  // The disk moves again: drain the FIFO while the writer finishes.
  std::thread drain([reader] {
    char buf[65536];
    ::fcntl(reader, F_SETFL, 0);  // blocking reads until the writer closes
    while (::read(reader, buf, sizeof buf) > 0) {
    }
  });
  w.stop();
  drain.join();
  ::close(reader);
  const RecordingCounters c = w.counters();
  EXPECT_EQ(c.items_queued, accepted);
  EXPECT_EQ(c.items_queued + c.items_dropped_queue_full, kItems);
  EXPECT_EQ(c.queue_max_items, kCapacity);
  EXPECT_EQ(c.marks_csv_write_errors, 0u);
  // Every accepted sample is in the Chapter 10 file (read by the independent reader).
  const auto f = ch10read::read_file((dir / "out.ch10").string());
  EXPECT_TRUE(f.stop_reason.empty()) << f.stop_reason;
  std::size_t messages = 0;
  for (const auto& p : f.packets)
    if (p.data_type == 0x30) messages += ch10read::decode_message_f0(p)->size();
  EXPECT_EQ(messages, accepted);
  fs::remove_all(dir);
}

TEST(RecordingWriter, CsvWriteErrorsAreCounted) {
  // /dev/full: every flush fails with ENOSPC, a real write error the old fprintf code ignored.
  if (!fs::exists("/dev/full")) GTEST_SKIP() << "no /dev/full";
  RecordingWriter w;
  ASSERT_EQ(w.open_rigid_csv("/dev/full"), 0);
  w.start();
  for (std::uint32_t k = 0; k < 200; ++k) {
    RecordingItem it = item(k);
    it.rigid_rows = std::string(4000, 'r') + "\n";
    w.push(std::move(it));
  }
  w.stop();
  const RecordingCounters c = w.counters();
  EXPECT_GT(c.rigid_csv_write_errors + c.rigid_csv_close_errors, 0u);
  EXPECT_TRUE(w.had_errors());
}

// Which output a test puts on a failing disk; the others stay healthy.
enum class FailingOutput { kChapter10, kFtiCsv, kMarksCsv, kRigidCsv, kClearanceCsv };

// Records 300 exposures to all five files, `failing` on a disk that refuses writes (a CSV on
// /dev/full, ENOSPC; the Chapter 10 file under a 20 kB RLIMIT_FSIZE, EFBIG), the healthy CSVs on
// /dev/null (never limited) and a healthy Chapter 10 file in `dir`. Runs in a child process so
// the file-size limit stays there; returns {"recording": ..., "outputs": ...} of the stats.
nlohmann::json record_with_one_failing_output(FailingOutput failing, const fs::path& dir) {
  int pipefd[2];
  if (::pipe(pipefd) != 0) return {};
  const pid_t child = ::fork();
  if (child == 0) {
    ::close(pipefd[0]);
    if (failing == FailingOutput::kChapter10) {
      std::signal(SIGXFSZ, SIG_IGN);  // write() then fails with EFBIG instead of killing us
      const rlimit limit{20'000, 20'000};
      if (::setrlimit(RLIMIT_FSIZE, &limit) != 0) _exit(3);
    }
    const auto path_for = [&](FailingOutput o) {
      return failing == o ? std::string("/dev/full") : std::string("/dev/null");
    };
    RecordingWriter w;
    output::Chapter10Config ch10;
    ch10.sync = output::Chapter10Sync::kNone;
    if (w.open_ch10((dir / "out.ch10").string(), ch10) != 0 ||
        w.open_csv(path_for(FailingOutput::kFtiCsv)) != 0 ||
        w.open_marks_csv(path_for(FailingOutput::kMarksCsv)) != 0 ||
        w.open_rigid_csv(path_for(FailingOutput::kRigidCsv)) != 0 ||
        w.open_clearance_csv(path_for(FailingOutput::kClearanceCsv)) != 0)
      _exit(4);
    w.start();
    for (std::uint32_t k = 0; k < 300; ++k) {
      RecordingItem it = item(k);
      it.rigid_rows = text_line(4001, 'r');
      it.clearance_rows = text_line(4001, 'c');
      w.push(std::move(it));
    }
    w.stop();
    output::InetxSender no_inetx;
    const std::string text = nlohmann::json{{"recording", recording_stats_json(w, "out.ch10")},
                                            {"outputs", outputs_stats_json(no_inetx, w)}}
                                 .dump();
    (void)!::write(pipefd[1], text.data(), text.size());
    _exit(0);
  }
  ::close(pipefd[1]);
  std::string text;
  char buf[4096];
  for (ssize_t n; (n = ::read(pipefd[0], buf, sizeof buf)) > 0;)
    text.append(buf, static_cast<std::size_t>(n));
  ::close(pipefd[0]);
  int status = 0;
  ::waitpid(child, &status, 0);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << "writer child failed";
  return nlohmann::json::parse(text, nullptr, false);
}

TEST(RecordingWriter, EachOutputsFailuresMoveOnlyItsOwnCounters) {
  // The old code reported one "write_errors" summing every file's failures (and one shared
  // "close_errors"): a full disk under the rigid-body CSV read the same as a lost Chapter 10
  // recording. Each output on a failing disk in turn: its counters move, no other output's do.
  if (!fs::exists("/dev/full") || !fs::exists("/dev/null")) GTEST_SKIP() << "no /dev/full";
  const char* const csv_keys[][2] = {{"csv_write_errors", "csv_close_errors"},
                                     {"marks_csv_write_errors", "marks_csv_close_errors"},
                                     {"rigid_csv_write_errors", "rigid_csv_close_errors"},
                                     {"clearance_csv_write_errors", "clearance_csv_close_errors"}};
  const std::pair<FailingOutput, int> cases[] = {{FailingOutput::kChapter10, -1},
                                                 {FailingOutput::kFtiCsv, 0},
                                                 {FailingOutput::kMarksCsv, 1},
                                                 {FailingOutput::kRigidCsv, 2},
                                                 {FailingOutput::kClearanceCsv, 3}};
  for (const auto& [failing, failing_csv] : cases) {
    const fs::path dir = fresh_dir("st_recording_one_failing");
    const nlohmann::json s = record_with_one_failing_output(failing, dir);
    ASSERT_TRUE(s.is_object()) << "no stats from the writer child";
    const nlohmann::json& r = s.at("recording");
    const nlohmann::json& o = s.at("outputs");
    SCOPED_TRACE("failing csv " + std::to_string(failing_csv) + ": " + o.dump());
    EXPECT_FALSE(o.contains("write_errors")) << "the summed counter is gone";
    for (int k = 0; k < 4; ++k) {
      const std::uint64_t writes = r.at(csv_keys[k][0]), closes = r.at(csv_keys[k][1]);
      EXPECT_EQ(o.at(csv_keys[k][0]), writes);
      EXPECT_EQ(o.at(csv_keys[k][1]), closes);
      if (k == failing_csv)
        EXPECT_GT(writes, 0u) << csv_keys[k][0];
      else
        EXPECT_EQ(writes + closes, 0u) << csv_keys[k][0] << " moved for another file's failure";
    }
    const std::uint64_t ch10_writes = o.at("ch10_write_errors");
    EXPECT_EQ(r.at("chapter10").at("write_errors"), ch10_writes);
    if (failing == FailingOutput::kChapter10) {
      EXPECT_GT(ch10_writes, 0u);
    } else {
      EXPECT_EQ(ch10_writes, 0u);
      EXPECT_EQ(o.at("ch10_close_errors"), 0u);
      EXPECT_EQ(o.at("ch10_messages_dropped"), 0u);
      EXPECT_EQ(r.at("ch10_sample_write_errors"), 0u);
    }
    EXPECT_EQ(o.at("file_queue_dropped"), 0u);
    EXPECT_EQ(o.at("inetx_send_errors"), 0u);
    fs::remove_all(dir);
  }
}

TEST(RecordingWriter, RestartNeverOverwritesTheCsvFiles) {
  // The CSVs are part of the recording too: a second run on the same paths keeps the first
  // run's files and writes numbered ones (fti.001.csv, ...).
  const fs::path dir = fresh_dir("st_recording_restart");
  auto run = [&](std::uint32_t first, std::uint32_t n) {
    RecordingWriter w;
    EXPECT_EQ(w.open_csv((dir / "fti.csv").string()), 0);
    EXPECT_EQ(w.open_marks_csv((dir / "marks.csv").string()), 0);
    w.start();
    for (std::uint32_t k = first; k < first + n; ++k)
      w.push(item(k));
    w.stop();
    EXPECT_FALSE(w.had_errors());
    return std::make_pair(w.csv_path(), w.marks_csv_path());
  };
  const auto lines = [](const fs::path& p) {
    std::ifstream in(p);
    std::size_t n = 0;
    for (std::string l; std::getline(in, l);)
      ++n;
    return n;
  };
  run(0, 30);
  const auto second = run(100, 7);
  EXPECT_EQ(lines(dir / "fti.csv"), 31u) << "the first run's CSV was overwritten";
  EXPECT_EQ(lines(dir / "marks.csv"), 31u);
  EXPECT_EQ(second.first, (dir / "fti.001.csv").string());
  EXPECT_EQ(second.second, (dir / "marks.001.csv").string());
  EXPECT_EQ(lines(dir / "fti.001.csv"), 8u);
  fs::remove_all(dir);
}

TEST(RecordingWriter, RawObservationsReachTheFileInArrivalOrderWithAndWithoutSamples) {
  // Raw observations wake the writer only in bulk, with a sample, or after kRawMaxWaitMs: every
  // one must still reach the file, in the order pushed, whether samples follow them or not.
  const fs::path dir = fresh_dir("st_recording_raw");
  for (const bool with_samples : {true, false}) {
    SCOPED_TRACE(with_samples);
    const fs::path path = dir / (with_samples ? "with.ch10" : "without.ch10");
    RecordingWriter w;
    output::Chapter10Config cfg;
    cfg.sync = output::Chapter10Sync::kNone;
    cfg.raw_observations = true;
    ASSERT_EQ(w.open_ch10(path.string(), cfg), 0);
    ASSERT_TRUE(w.wants_raw());
    w.start();
    std::vector<std::vector<std::uint8_t>> sent;
    for (std::uint32_t k = 0; k < 300; ++k) {
      for (std::uint32_t c = 0; c < 4; ++c) {
        std::vector<std::uint8_t> bytes(20 + (k * 4 + c) % 50, static_cast<std::uint8_t>(k + c));
        msg::RawObservation r{};
        r.arrival_tai_ns = 1'900'000'000'000'000'000LL + k * 2'500'000LL + c * 1000;
        r.unit_id = static_cast<std::uint8_t>(c);
        r.flags = msg::raw_observation_flags::kAccepted;
        r.received_bytes = static_cast<std::uint32_t>(bytes.size());
        r.message_bytes = static_cast<std::uint16_t>(bytes.size());
        ASSERT_TRUE(w.push_raw(r, bytes));
        sent.push_back(bytes);
      }
      if (with_samples) {
        RecordingItem it;
        it.sample.trigger_seq = k;
        it.sample.store_id = 1;
        it.sample.exposure_mid_tai_ns = 1'900'000'000'000'000'000LL + k * 2'500'000LL;
        ASSERT_TRUE(w.push(std::move(it)));
      }
      if (k == 100) std::this_thread::sleep_for(std::chrono::milliseconds(60));  // the timeout
    }
    w.stop();
    EXPECT_FALSE(w.had_errors());
    const auto c = w.counters();
    EXPECT_EQ(c.raw_queued, sent.size());
    EXPECT_EQ(c.raw_dropped_queue_full + c.raw_dropped_queue_bytes + c.raw_write_errors, 0u);
    EXPECT_EQ(w.ch10().counters().raw_messages_written, sent.size());
    const auto got = ch10read::raw_observations(ch10read::read_file(path.string()));
    ASSERT_EQ(got.size(), sent.size());
    for (std::size_t i = 0; i < sent.size(); ++i)
      EXPECT_EQ(got[i].bytes, sent[i]) << i;
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace storetrack::hostapp
