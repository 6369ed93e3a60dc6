// The RecordingWriter takes all file I/O off the real-time thread. Its disk is made to stall for
// real: the marks CSV is a FIFO whose reader does not read, so the writer thread blocks in
// write() once the pipe buffer is full. The real-time side (push) must then neither block nor
// grow without bound: exactly the queue's capacity is held, every further item is counted as
// dropped, and once the "disk" moves again every held item reaches every file.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>

#include "recording_writer.hpp"
#include "storetrack/output/chapter10_reader.hpp"

namespace storetrack::hostapp {
namespace {

namespace fs = std::filesystem;

fs::path fresh_dir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / (name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

RecordingItem item(std::uint32_t k) {
  RecordingItem it;
  it.sample.trigger_seq = k;
  it.sample.store_id = 1;
  it.sample.exposure_mid_tai_ns = 1'900'000'000'000'000'000LL + k * 2'500'000LL;
  it.marks_rows = std::string(1000, 'm') + "\n";  // 1 kB per exposure: the pipe fills at 64
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
  EXPECT_GT(c.rigid_csv_write_errors + c.close_errors, 0u);
  EXPECT_GT(w.error_count(), 0u);
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
    EXPECT_EQ(w.error_count(), 0u);
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

}  // namespace
}  // namespace storetrack::hostapp
