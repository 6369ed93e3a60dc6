#include "storetrack/clock/clock_monitor.hpp"

#include <chrono>

namespace storetrack::clock {

ClockMonitor::ClockMonitor(ClockMonitorConfig config)
    : config_(std::move(config)),
      client_(config_.ptp4l),
      machine_(config_.lock),
      window_(config_.uncertainty.offset_window) {}

ClockMonitor::~ClockMonitor() {
  stop();
}

int ClockMonitor::start(bool thread) {
  if (const int rc = client_.open(); rc < 0) return rc;
  if (thread) {
    stopping_ = false;
    thread_ = std::thread([this] { run(); });
  }
  return 0;
}

void ClockMonitor::stop() {
  if (thread_.joinable()) {
    {
      std::lock_guard<std::mutex> lock(wake_mutex_);
      stopping_ = true;
    }
    wake_.notify_all();
    thread_.join();
  }
  client_.close();
}

void ClockMonitor::run() {
  const auto period = std::chrono::milliseconds(config_.poll_period_ms);
  auto next = std::chrono::steady_clock::now();
  std::unique_lock<std::mutex> lock(wake_mutex_);
  while (!stopping_) {
    lock.unlock();
    poll_once();
    lock.lock();
    next += period;
    // A poll that overran its period (a hung ptp4l: three reply timeouts) does not make the
    // next ones run back to back to catch up.
    if (next < std::chrono::steady_clock::now()) next = std::chrono::steady_clock::now();
    wake_.wait_until(lock, next, [this] { return stopping_; });
  }
}

PtpPoll ClockMonitor::query() {
  PtpPoll poll;
  ManagementReply reply;
  PortDataSet port;
  TimeStatusNp status;
  TimePropertiesDataSet properties;
  const bool have_port =
      client_.get(ManagementId::kPortDataSet, reply) == 0 && parse_port_data_set(reply.data, port);
  const bool have_status = client_.get(ManagementId::kTimeStatusNp, reply) == 0 &&
                           parse_time_status_np(reply.data, status);
  const bool have_properties = client_.get(ManagementId::kTimePropertiesDataSet, reply) == 0 &&
                               parse_time_properties(reply.data, properties);
  poll.answered = have_port && have_status;
  if (have_port) poll.port_state = port.port_state;
  if (have_status) {
    poll.gm_present = status.gm_present;
    poll.master_offset_ns = status.master_offset_ns;
    poll.ingress_time_ns = status.ingress_time_ns;
  }
  poll.time_traceable = have_properties && properties.time_traceable();
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ++stats_.polls;
  if (poll.answered) ++stats_.answered_polls;
  stats_.port_state = poll.port_state;
  stats_.gm_present = poll.gm_present;
  stats_.time_traceable = poll.time_traceable;
  stats_.master_offset_ns = poll.master_offset_ns;
  stats_.ingress_time_ns = poll.ingress_time_ns;
  if (have_status) stats_.gm_identity = status.gm_identity;
  return poll;
}

time::ClockState ClockMonitor::poll_once() {
  const PtpPoll poll = query();
  const time::ClockState before = machine_.state();
  const time::MonotonicNs now_ns = time::monotonic_now_ns();
  const time::ClockState now = machine_.update(poll, now_ns);
  offset_ns_.store(machine_.offset_ns(), std::memory_order_relaxed);
  if (machine_.new_measurement()) {
    window_.add(poll.master_offset_ns);
    rms_ns_.store(window_.rms_ns(), std::memory_order_relaxed);
    measured_at_ns_.store(now_ns, std::memory_order_relaxed);
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++stats_.new_offsets;
    stats_.offset_rms_ns = window_.rms_ns();
  }
  holding_.store(machine_.holding(), std::memory_order_release);
  state_.store(static_cast<std::uint8_t>(now), std::memory_order_relaxed);
  if (now != before) {
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++stats_.transitions;
  }
  return now;
}

ClockMonitorStats ClockMonitor::stats() const {
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ClockMonitorStats s = stats_;
  s.client = client_.stats();
  return s;
}

}  // namespace storetrack::clock
