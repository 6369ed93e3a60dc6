#include "recording_writer.hpp"

#include <spdlog/spdlog.h>
#include <algorithm>
#include <chrono>

namespace storetrack::hostapp {

RecordingWriter::RecordingWriter(std::size_t max_items, std::size_t max_text_bytes)
    : max_items_(std::max<std::size_t>(1, max_items)), max_text_bytes_(max_text_bytes) {}

RecordingWriter::~RecordingWriter() {
  stop();
}

int RecordingWriter::open_ch10(const std::string& path, const output::Chapter10Config& config) {
  const int rc = ch10_.open(path, config);
  ch10_open_ = rc == 0;
  raw_enabled_ = config.raw_observations;
  return rc;
}
namespace {

// A restarted host never overwrites: the numbered name it chose instead is logged.
int report_created(int rc, const std::string& requested, const std::string& created) {
  if (rc == 0 && created != requested)
    spdlog::warn("storetrack-host: '{}' exists and is kept; writing '{}'", requested, created);
  return rc;
}

std::size_t text_bytes(const RecordingItem& item) {
  return item.marks_rows.size() + item.rigid_rows.size() + item.clearance_rows.size();
}

}  // namespace

int RecordingWriter::open_csv(const std::string& path) {
  const int rc = csv_.open(path);
  csv_open_ = rc == 0;
  return report_created(rc, path, csv_.path());
}
int RecordingWriter::open_marks_csv(const std::string& path) {
  return report_created(marks_.open(path, kMarksCsvHeader), path, marks_.path());
}
int RecordingWriter::open_rigid_csv(const std::string& path) {
  return report_created(rigid_.open(path, kRigidCsvHeader), path, rigid_.path());
}
int RecordingWriter::open_clearance_csv(const std::string& path) {
  return report_created(clearance_.open(path, kClearanceCsvHeader), path, clearance_.path());
}
bool RecordingWriter::has_files() const {
  return ch10_open_ || csv_open_ || marks_.is_open() || rigid_.is_open() || clearance_.is_open();
}

void RecordingWriter::start() {
  if (started_) return;
  started_ = true;
  thread_ = std::thread([this] { run(); });
}

bool RecordingWriter::push(RecordingItem&& item) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const std::size_t text = text_bytes(item);
    if (stopping_ || queue_.size() >= max_items_ ||
        (!queue_.empty() && queued_text_bytes_ + text > max_text_bytes_)) {
      ++counters_.items_dropped_queue_full;
      return false;
    }
    queued_text_bytes_ += text;
    queue_.push_back(std::move(item));
    ++counters_.items_queued;
    counters_.queue_max_items = std::max<std::uint64_t>(counters_.queue_max_items, queue_.size());
    counters_.queue_max_text_bytes =
        std::max<std::uint64_t>(counters_.queue_max_text_bytes, queued_text_bytes_);
  }
  cv_.notify_one();
  return true;
}

bool RecordingWriter::push_raw(const msg::RawObservation& record,
                               std::span<const std::uint8_t> bytes) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_ || raw_queue_.size() >= kRawQueueItems) {
      ++counters_.raw_dropped_queue_full;
      return false;
    }
    if (raw_queued_bytes_ + bytes.size() > kRawQueueBytes) {
      ++counters_.raw_dropped_queue_bytes;
      return false;
    }
    raw_queue_.push_back(RawRecordingItem{record, {bytes.begin(), bytes.end()}});
    raw_queued_bytes_ += bytes.size();
    ++counters_.raw_queued;
    counters_.raw_queue_max_items =
        std::max<std::uint64_t>(counters_.raw_queue_max_items, raw_queue_.size());
    if (raw_queue_.size() < kRawWakeItems) return true;
  }
  cv_.notify_one();
  return true;
}

void RecordingWriter::run() {
  std::unique_lock<std::mutex> lock(mutex_);
  for (;;) {
    // Raw observations alone wake it only in bulk (push_raw); the timeout bounds their wait.
    cv_.wait_for(lock, std::chrono::milliseconds(kRawMaxWaitMs), [this] {
      return stopping_ || !queue_.empty() || raw_queue_.size() >= kRawWakeItems;
    });
    while (!queue_.empty() || !raw_queue_.empty()) {
      // The observations queued so far first: an exposure's sample is pushed after them.
      while (!raw_queue_.empty()) {
        RawRecordingItem raw = std::move(raw_queue_.front());
        raw_queue_.pop_front();
        raw_queued_bytes_ -= raw.bytes.size();
        lock.unlock();
        write_raw(raw);
        lock.lock();
      }
      if (queue_.empty()) break;
      RecordingItem item = std::move(queue_.front());
      queue_.pop_front();
      queued_text_bytes_ -= text_bytes(item);
      lock.unlock();
      write(item);
      lock.lock();
    }
    if (stopping_) return;
  }
}

// Runs on the writer thread only; its counters are merged under the lock.
void RecordingWriter::write(const RecordingItem& item) {
  RecordingCounters d;
  if (ch10_open_ && ch10_.write(item.sample) != 0) ++d.ch10_sample_write_errors;
  if (csv_open_ && csv_.write(item.sample) != 0) ++d.csv_write_errors;
  if (marks_.is_open() && !item.marks_rows.empty() && marks_.write(item.marks_rows) != 0)
    ++d.marks_csv_write_errors;
  if (rigid_.is_open() && !item.rigid_rows.empty() && rigid_.write(item.rigid_rows) != 0)
    ++d.rigid_csv_write_errors;
  if (clearance_.is_open() && !item.clearance_rows.empty() &&
      clearance_.write(item.clearance_rows) != 0)
    ++d.clearance_csv_write_errors;
  std::lock_guard<std::mutex> lock(mutex_);
  counters_.ch10_sample_write_errors += d.ch10_sample_write_errors;
  counters_.csv_write_errors += d.csv_write_errors;
  counters_.marks_csv_write_errors += d.marks_csv_write_errors;
  counters_.rigid_csv_write_errors += d.rigid_csv_write_errors;
  counters_.clearance_csv_write_errors += d.clearance_csv_write_errors;
}

void RecordingWriter::write_raw(const RawRecordingItem& item) {
  if (ch10_open_ && ch10_.write_raw(item.record, item.bytes) != 0) {
    std::lock_guard<std::mutex> lock(mutex_);
    ++counters_.raw_write_errors;
  }
}

void RecordingWriter::stop() {
  if (stopped_) return;
  stopped_ = true;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  cv_.notify_one();
  if (thread_.joinable()) thread_.join();
  // The Chapter 10 writer counts its own close errors (ch10().counters().close_errors).
  if (ch10_open_) ch10_.close();
  const bool csv_failed = csv_open_ && csv_.close() != 0;
  const bool marks_failed = marks_.close() != 0;
  const bool rigid_failed = rigid_.close() != 0;
  const bool clearance_failed = clearance_.close() != 0;
  std::lock_guard<std::mutex> lock(mutex_);
  counters_.csv_close_errors += csv_failed ? 1 : 0;
  counters_.marks_csv_close_errors += marks_failed ? 1 : 0;
  counters_.rigid_csv_close_errors += rigid_failed ? 1 : 0;
  counters_.clearance_csv_close_errors += clearance_failed ? 1 : 0;
  counters_.csv_rows = csv_.rows_written();
}

RecordingCounters RecordingWriter::counters() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return counters_;
}

bool RecordingWriter::had_errors() const {
  const RecordingCounters c = counters();
  const output::Chapter10Counters& cc = ch10_.counters();
  const std::uint64_t losses[] = {c.items_dropped_queue_full,
                                  c.ch10_sample_write_errors,
                                  c.csv_write_errors,
                                  c.csv_close_errors,
                                  c.marks_csv_write_errors,
                                  c.marks_csv_close_errors,
                                  c.rigid_csv_write_errors,
                                  c.rigid_csv_close_errors,
                                  c.clearance_csv_write_errors,
                                  c.clearance_csv_close_errors,
                                  cc.write_errors,
                                  cc.sync_errors,
                                  cc.close_errors,
                                  cc.messages_dropped,
                                  c.raw_dropped_queue_full,
                                  c.raw_dropped_queue_bytes,
                                  c.raw_write_errors,
                                  cc.raw_messages_dropped};
  for (std::uint64_t n : losses)
    if (n != 0) return true;
  return false;
}

}  // namespace storetrack::hostapp
