// All file output of storetrack-host (Chapter 10 with fdatasync, FTI CSV, marks and rigid-body
// CSVs) on ONE thread of its own, so a slow or failing disk never delays the real-time path
// (receive -> process -> iNET-X). The real-time thread hands over whole items through a bounded
// queue and never blocks: when the queue is full the item is dropped and counted.
// Bound: kQueueItems items and kQueueTextBytes bytes of CSV text (docs/reliability.md,
// "Recording").
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <string>
#include <thread>

#include "diagnostic_csv.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/output/chapter10_writer.hpp"
#include "storetrack/output/csv_writer.hpp"

namespace storetrack::hostapp {

/// One exposure's output for the files.
struct RecordingItem {
  msg::FtiSample sample{};
  std::string marks_rows;  ///< formatted --marks-csv rows (empty when that file is off)
  std::string rigid_rows;  ///< formatted --rigid-csv rows
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
};

class RecordingWriter {
 public:
  static constexpr std::size_t kQueueItems = 4096;           // ~10 s at 400 exposures/s
  static constexpr std::size_t kQueueTextBytes = 64u << 20;  // 64 MiB of CSV text
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
  bool has_files() const;
  bool wants_marks_rows() const { return marks_.is_open(); }
  bool wants_rigid_rows() const { return rigid_.is_open(); }

  void start();
  /// Never blocks; false (and counted) when the queue is full.
  bool push(RecordingItem&& item);
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

 private:
  void run();
  void write(const RecordingItem& item);

  output::Chapter10Writer ch10_;
  bool ch10_open_ = false;
  output::FtiCsvWriter csv_;
  bool csv_open_ = false;
  CsvFile marks_, rigid_;

  const std::size_t max_items_, max_text_bytes_;
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<RecordingItem> queue_;
  std::size_t queued_text_bytes_ = 0;
  RecordingCounters counters_;
  bool stopping_ = false, started_ = false, stopped_ = false;
  std::thread thread_;
};

}  // namespace storetrack::hostapp
