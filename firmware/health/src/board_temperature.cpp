#include "storetrack/health/board_temperature.hpp"

#include <chrono>
#include <utility>

#include "storetrack/health/unit_state.hpp"

namespace storetrack::health {

BoardTemperatureSampler::BoardTemperatureSampler(std::string root, int period_ms,
                                                 std::atomic<std::int16_t>& out)
    : root_(std::move(root)), period_ms_(period_ms), out_(out) {}

BoardTemperatureSampler::~BoardTemperatureSampler() {
  stop();
}

void BoardTemperatureSampler::start() {
  if (thread_.joinable()) return;
  stopping_ = false;
  thread_ = std::thread([this] { run(); });
}

void BoardTemperatureSampler::stop() {
  if (!thread_.joinable()) return;
  {
    std::lock_guard<std::mutex> lock(wake_mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  thread_.join();
}

void BoardTemperatureSampler::run() {
  const auto period = std::chrono::milliseconds(period_ms_);
  auto next = std::chrono::steady_clock::now();
  std::unique_lock<std::mutex> lock(wake_mutex_);
  while (!stopping_) {
    lock.unlock();
    out_.store(read_board_temp_cdeg(root_), std::memory_order_relaxed);
    samples_.fetch_add(1, std::memory_order_relaxed);
    lock.lock();
    next += period;
    // A read that overran its period is not followed by others back to back.
    if (next < std::chrono::steady_clock::now()) next = std::chrono::steady_clock::now();
    wake_.wait_until(lock, next, [this] { return stopping_; });
  }
}

}  // namespace storetrack::health
