// All file output of storetrack-host (Chapter 10 with fdatasync, FTI CSV, marks, rigid-body and
// clearance CSVs) on ONE thread of its own, so a slow or failing disk never delays the real-time
// path (receive -> process -> iNET-X). The real-time thread hands over whole items through a
// bounded queue and never blocks: when the queue is full the item is dropped and counted. Bound:
// kQueueItems items and kQueueTextBytes bytes of CSV text (docs/reliability.md, "Recording").
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "diagnostic_csv.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/output/chapter10_writer.hpp"
#include "storetrack/output/csv_writer.hpp"

namespace storetrack::hostapp {

/// One exposure's output for the files.
struct RecordingItem {
  msg::FtiSample sample{};
  std::string marks_rows;      ///< formatted --marks-csv rows (empty when that file is off)
  std::string rigid_rows;      ///< formatted --rigid-csv rows
  std::string clearance_rows;  ///< formatted --clearance-csv rows
};

/// One observation message as received, for the Chapter 10 raw channel.
struct RawRecordingItem {
  msg::RawObservation record{};
  std::vector<std::uint8_t> bytes;
};

// One counter per file and kind of failure: a full disk under the marks CSV never shows as an
// FTI CSV or Chapter 10 error. The Chapter 10 file's packet-level counters (write, sync, close,
// truncation) are its writer's own: ch10().counters().
struct RecordingCounters {
  std::uint64_t items_queued = 0;
  std::uint64_t items_dropped_queue_full = 0;  ///< never reached any file
  std::uint64_t queue_max_items = 0;
  std::uint64_t queue_max_text_bytes = 0;
  std::uint64_t ch10_sample_write_errors = 0;  ///< samples whose Chapter 10 write() failed
  std::uint64_t csv_rows = 0;
  std::uint64_t csv_write_errors = 0;  ///< --csv (FTI samples) rows not written
  std::uint64_t csv_close_errors = 0;  ///< --csv close (last buffered rows) failed
  std::uint64_t marks_csv_write_errors = 0;
  std::uint64_t marks_csv_close_errors = 0;
  std::uint64_t rigid_csv_write_errors = 0;
  std::uint64_t rigid_csv_close_errors = 0;
  std::uint64_t clearance_csv_write_errors = 0;
  std::uint64_t clearance_csv_close_errors = 0;
  // Raw observations (their own queue bound, so a burst of them never crowds out samples).
  std::uint64_t raw_queued = 0;
  std::uint64_t raw_dropped_queue_full = 0;   ///< the raw queue held kRawQueueItems already
  std::uint64_t raw_dropped_queue_bytes = 0;  ///< ... or kRawQueueBytes of message bytes
  std::uint64_t raw_queue_max_items = 0;
  std::uint64_t raw_write_errors = 0;  ///< write_raw() failed (the writer counts which packet)
};

class RecordingWriter {
 public:
  static constexpr std::size_t kQueueItems = 4096;           // ~10 s at 400 exposures/s
  static constexpr std::size_t kQueueTextBytes = 64u << 20;  // 64 MiB of CSV text
  // Raw observations: ~10 s of 8 cameras at 400 fps, and at most 64 MiB of their bytes.
  static constexpr std::size_t kRawQueueItems = 32768;
  static constexpr std::size_t kRawQueueBytes = 64u << 20;
  // The writer thread is woken for raw observations only once this many wait (else the next
  // exposure's push, or its own 20 ms timeout, picks them up): a wake-up per datagram cost the
  // real-time thread a futex call and the 2 cores a context switch each.
  static constexpr std::size_t kRawWakeItems = 256;
  static constexpr int kRawMaxWaitMs = 20;
  explicit RecordingWriter(std::size_t max_items = kQueueItems,
                           std::size_t max_text_bytes = kQueueTextBytes);
  ~RecordingWriter();
  RecordingWriter(const RecordingWriter&) = delete;
  RecordingWriter& operator=(const RecordingWriter&) = delete;

  // Open the files (before start()); each returns 0 or -errno.
  int open_ch10(const std::string& path, const output::Chapter10Config& config);
  int open_csv(const std::string& path);
  int open_marks_csv(const std::string& path);
  int open_rigid_csv(const std::string& path);
  int open_clearance_csv(const std::string& path);
  bool has_files() const;
  bool wants_marks_rows() const { return marks_.is_open(); }
  bool wants_rigid_rows() const { return rigid_.is_open(); }
  bool wants_clearance_rows() const { return clearance_.is_open(); }

  void start();
  /// Never blocks; false (and counted) when the queue is full.
  bool push(RecordingItem&& item);
  /// True when the Chapter 10 file records raw observations (push_raw() takes them).
  bool wants_raw() const { return ch10_open_ && raw_enabled_; }
  /// Copies one received observation message into the raw queue; never blocks, false (and
  /// counted by reason) when that queue is full. Written in arrival order, before the samples
  /// queued after it.
  bool push_raw(const msg::RawObservation& record, std::span<const std::uint8_t> bytes);
  /// Writes what is queued, closes every file, joins the thread. Safe to call twice.
  void stop();

  // Read after stop().
  RecordingCounters counters() const;
  /// True when any sample or row is lost or not known to be on disk: queue drops, write, sync
  /// and close errors of any file (the exit status is then 1; the counters say which).
  bool had_errors() const;
  const output::Chapter10Writer& ch10() const { return ch10_; }
  bool ch10_open() const { return ch10_open_; }
  /// The CSV files created (numbered names when the requested ones existed), "" when off.
  const std::string& csv_path() const { return csv_.path(); }
  const std::string& marks_csv_path() const { return marks_.path(); }
  const std::string& rigid_csv_path() const { return rigid_.path(); }
  const std::string& clearance_csv_path() const { return clearance_.path(); }

 private:
  void run();
  void write(const RecordingItem& item);
  void write_raw(const RawRecordingItem& item);

  output::Chapter10Writer ch10_;
  bool ch10_open_ = false;
  bool raw_enabled_ = false;
  output::FtiCsvWriter csv_;
  bool csv_open_ = false;
  CsvFile marks_, rigid_, clearance_;

  const std::size_t max_items_, max_text_bytes_;
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<RecordingItem> queue_;
  std::deque<RawRecordingItem> raw_queue_;
  std::size_t raw_queued_bytes_ = 0;
  std::size_t queued_text_bytes_ = 0;
  RecordingCounters counters_;
  bool stopping_ = false, started_ = false, stopped_ = false;
  std::thread thread_;
};

}  // namespace storetrack::hostapp
