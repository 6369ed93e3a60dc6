#include "storetrack/trigger/gpio_trigger.hpp"

#include <gpiod.h>
#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <ctime>

namespace storetrack::trigger {
namespace {

timespec to_timespec(std::int64_t ns) {
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(ns / time::kNsPerSecond);
  ts.tv_nsec = static_cast<long>(ns % time::kNsPerSecond);
  return ts;
}

std::int64_t to_ns(const timespec& ts) {
  return static_cast<std::int64_t>(ts.tv_sec) * time::kNsPerSecond + ts.tv_nsec;
}

std::string describe(const std::string& chip, const std::string& what, int err) {
  return "GPIO " + chip + ": " + what + ": " + std::strerror(err);
}

}  // namespace

int validate(const GpioMasterConfig& c, std::string* why) {
  std::string reason;
  if (!(c.rate_hz > 0.0 && c.rate_hz <= 400.0)) {
    reason = "trigger rate must be in (0, 400] Hz";
  } else if (c.lines.empty()) {
    reason = "at least one output line is needed";
  } else if (c.pulse_width_ns <= 0 || static_cast<double>(c.pulse_width_ns) >= 0.9e9 / c.rate_hz) {
    reason = "pulse width must be > 0 and < 90 % of the trigger period";
  } else if (c.max_late_ns < 0 || static_cast<double>(c.max_late_ns) >= 0.5e9 / c.rate_hz) {
    reason = "max_late_ns must be >= 0 and < half the trigger period";
  }
  if (why != nullptr) *why = reason;
  return reason.empty() ? 0 : -EINVAL;
}

// ---------------------------------------------------------------------------------- master
GpioMasterTrigger::GpioMasterTrigger(GpioMasterConfig config) : config_(std::move(config)) {
  name_ = config_.chip + " line";
  for (unsigned l : config_.lines) {
    name_ += ' ';
    name_ += std::to_string(l);
  }
  name_ += " (master)";
}

GpioMasterTrigger::~GpioMasterTrigger() {
  stop();
}

int GpioMasterTrigger::start() {
  if (running_.load()) return 0;
  if (int rc = validate(config_, &error_); rc < 0) return rc;
  if (int rc = request_lines(); rc < 0) return rc;
  running_.store(true);
  thread_ = std::thread([this] { run(); });
  return 0;
}

int GpioMasterTrigger::request_lines() {
  chip_ = gpiod_chip_open_lookup(config_.chip.c_str());
  if (chip_ == nullptr) {
    const int err = errno != 0 ? errno : ENODEV;
    error_ = describe(config_.chip, "cannot open chip", err);
    return -err;
  }
  const int flags = config_.active_low ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0;
  for (unsigned offset : config_.lines) {
    gpiod_line* line = gpiod_chip_get_line(chip_, offset);
    if (line == nullptr ||
        gpiod_line_request_output_flags(line, config_.consumer.c_str(), flags, 0) < 0) {
      const int err = errno != 0 ? errno : EINVAL;
      error_ = describe(config_.chip, "cannot request output line " + std::to_string(offset), err);
      release_lines();
      return -err;
    }
    lines_.push_back(line);
  }
  return 0;
}

void GpioMasterTrigger::release_lines() {
  for (gpiod_line* line : lines_) {
    gpiod_line_set_value(line, 0);
    gpiod_line_release(line);
  }
  lines_.clear();
  if (chip_ != nullptr) {
    gpiod_chip_close(chip_);
    chip_ = nullptr;
  }
}

int GpioMasterTrigger::stop() {
  running_.store(false);
  if (thread_.joinable()) thread_.join();
  release_lines();
  return 0;
}

// Sets every line; false when any could not be set.
bool GpioMasterTrigger::drive(int value) {
  bool ok = !lines_.empty();
  for (gpiod_line* line : lines_)
    ok = gpiod_line_set_value(line, value) == 0 && ok;
  return ok;
}

void GpioMasterTrigger::run() {
  if (config_.realtime_priority) {
    sched_param sp{};
    sp.sched_priority = 50;
    // Refused without CAP_SYS_NICE / rtprio limits; the schedule still holds, only jitter grows.
    pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
  }
  const std::int64_t period = static_cast<std::int64_t>(std::llround(1e9 / config_.rate_hz));
  const std::int64_t max_late = config_.max_late_ns > 0 ? config_.max_late_ns : period / 8;
  // Phase-lock to the monotonic clock: pulses on whole multiples of the period.
  const std::int64_t now = time::monotonic_now_ns();
  std::int64_t k = now / period + 2;
  std::uint32_t count = 0;
  int failed_in_a_row = 0;
  while (running_.load(std::memory_order_relaxed)) {
    const std::int64_t t_k = k * period;
    timespec ts = to_timespec(t_k);
    int rc;
    do {
      rc = clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr);
    } while (rc == EINTR);
    const std::int64_t before = time::monotonic_now_ns();
    const std::int64_t late = before - t_k;
    if (late > max_late_ns_.load(std::memory_order_relaxed)) max_late_ns_.store(late);
    if (late > max_late) {
      // Too late for this slot: skip it and every whole period missed, never drive a pulse off
      // the grid or bunch pulses. The next slot may already be due; the loop sees to it.
      const std::int64_t skipped = std::max<std::int64_t>(1, late / period);
      overruns_.fetch_add(static_cast<std::uint64_t>(skipped));
      k += skipped;
      continue;
    }
    if (!drive(1)) {
      // A line that cannot be driven (connector, a GPIO chip gone): this pulse is lost (counted
      // once), the next ones keep their place on the grid. The generator never stops by itself;
      // after a run of failures the lines are requested again, once a second (off the frame
      // path).
      line_errors_.fetch_add(1, std::memory_order_relaxed);
      drive(0);  // a line that did take the rising edge must not stay high
      if (++failed_in_a_row >= kLineErrorsBeforeReopen &&
          failed_in_a_row % std::max<int>(1, static_cast<int>(1e9 / period)) == 0) {
        release_lines();
        if (request_lines() == 0) reopens_.fetch_add(1, std::memory_order_relaxed);
      }
      ++k;
      continue;
    }
    failed_in_a_row = 0;
    const std::int64_t after = time::monotonic_now_ns();
    const std::uint64_t w = write_index_.load(std::memory_order_relaxed);
    if (w - read_index_.load(std::memory_order_acquire) >= kRing) {
      dropped_.fetch_add(1, std::memory_order_relaxed);
    } else {
      ring_[w % kRing] = TriggerEdge{before + (after - before) / 2, count};
      write_index_.store(w + 1, std::memory_order_release);
    }
    ++count;
    edges_.fetch_add(1, std::memory_order_relaxed);
    timespec off = to_timespec(t_k + config_.pulse_width_ns);
    do {
      rc = clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &off, nullptr);
    } while (rc == EINTR);
    drive(0);
    ++k;
  }
}

int GpioMasterTrigger::read_edges(std::span<TriggerEdge> out, int timeout_ms) {
  const std::int64_t deadline = time::monotonic_now_ns() + std::int64_t{timeout_ms} * 1'000'000;
  for (;;) {
    const std::uint64_t r = read_index_.load(std::memory_order_relaxed);
    const std::uint64_t w = write_index_.load(std::memory_order_acquire);
    const std::size_t n = std::min<std::uint64_t>(w - r, out.size());
    if (n > 0 || timeout_ms <= 0 || time::monotonic_now_ns() >= deadline) {
      for (std::size_t i = 0; i < n; ++i)
        out[i] = ring_[(r + i) % kRing];
      read_index_.store(r + n, std::memory_order_release);
      return static_cast<int>(n);
    }
    timespec nap =
        to_timespec(1'000'000);  // edges are stamped by the generator: latency is harmless
    nanosleep(&nap, nullptr);
  }
}

TriggerLineStats GpioMasterTrigger::stats() const {
  TriggerLineStats s;
  s.edges = edges_.load();
  s.overruns = overruns_.load();
  s.max_late_ns = max_late_ns_.load();
  s.dropped_edges = dropped_.load();
  s.line_errors = line_errors_.load();
  s.reopens = reopens_.load();
  return s;
}

// ----------------------------------------------------------------------------------- slave
GpioSlaveTrigger::GpioSlaveTrigger(GpioSlaveConfig config) : config_(std::move(config)) {
  name_ = config_.chip + " line " + std::to_string(config_.line) + " (slave)";
}

GpioSlaveTrigger::~GpioSlaveTrigger() {
  stop();
}

int GpioSlaveTrigger::start() {
  if (line_ != nullptr) return 0;
  wanted_ = true;
  return request_line();
}

int GpioSlaveTrigger::request_line() {
  chip_ = gpiod_chip_open_lookup(config_.chip.c_str());
  if (chip_ == nullptr) {
    const int err = errno != 0 ? errno : ENODEV;
    error_ = describe(config_.chip, "cannot open chip", err);
    return -err;
  }
  line_ = gpiod_chip_get_line(chip_, config_.line);
  const int flags = config_.active_low ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0;
  if (line_ == nullptr ||
      gpiod_line_request_rising_edge_events_flags(line_, config_.consumer.c_str(), flags) < 0) {
    const int err = errno != 0 ? errno : EINVAL;
    error_ =
        describe(config_.chip,
                 "cannot request rising-edge events on line " + std::to_string(config_.line), err);
    line_ = nullptr;
    release_line();
    return -err;
  }
  return 0;
}

void GpioSlaveTrigger::release_line() {
  if (line_ != nullptr) {
    gpiod_line_release(line_);
    line_ = nullptr;
  }
  if (chip_ != nullptr) {
    gpiod_chip_close(chip_);
    chip_ = nullptr;
  }
}

int GpioSlaveTrigger::stop() {
  wanted_ = false;
  release_line();
  return 0;
}

// Waiting for or reading edge events failed: counted and returned; after a run of failures the
// line is released and requested again (a chip that went away and came back: its old line
// handle stays dead), at most once a second.
int GpioSlaveTrigger::line_error() {
  const int err = errno != 0 ? errno : EIO;
  ++stats_.line_errors;
  if (++consecutive_errors_ >= kLineErrorsBeforeReopen) {
    consecutive_errors_ = 0;
    release_line();
    reopen_due_ns_ = time::monotonic_now_ns();
  }
  return -err;
}

// The line is down: no edges until the next try is due (waiting up to timeout_ms, so that a
// caller does not spin); a failed try is a line error, counted and returned.
int GpioSlaveTrigger::reopen_if_due(int timeout_ms) {
  if (!wanted_) return -ENOTCONN;  // never started, or stopped by the caller
  const std::int64_t now = time::monotonic_now_ns();
  if (now < reopen_due_ns_) {
    const std::int64_t wait_ns = std::min<std::int64_t>(
        reopen_due_ns_ - now, std::int64_t{std::max(timeout_ms, 0)} * 1'000'000);
    const timespec nap = to_timespec(wait_ns);
    nanosleep(&nap, nullptr);
    return 0;
  }
  reopen_due_ns_ = now + time::kNsPerSecond;
  if (request_line() != 0) {
    ++stats_.line_errors;
    return -ENODEV;
  }
  ++stats_.reopens;
  return 0;
}

int GpioSlaveTrigger::read_edges(std::span<TriggerEdge> out, int timeout_ms) {
  if (line_ == nullptr) return reopen_if_due(timeout_ms);
  if (out.empty()) return 0;
  const timespec timeout = to_timespec(std::int64_t{std::max(timeout_ms, 0)} * 1'000'000);
  const int ready = gpiod_line_event_wait(line_, &timeout);
  if (ready < 0) return line_error();
  if (ready == 0) return 0;
  std::array<gpiod_line_event, 16> events{};
  const unsigned want = static_cast<unsigned>(std::min(out.size(), events.size()));
  const int n = gpiod_line_event_read_multiple(line_, events.data(), want);
  if (n < 0) return line_error();
  consecutive_errors_ = 0;
  int written = 0;
  for (int i = 0; i < n; ++i) {
    if (events[static_cast<std::size_t>(i)].event_type != GPIOD_LINE_EVENT_RISING_EDGE) continue;
    out[static_cast<std::size_t>(written++)] =
        TriggerEdge{to_ns(events[static_cast<std::size_t>(i)].ts), line_count_++};
    ++stats_.edges;
  }
  return written;
}

}  // namespace storetrack::trigger
