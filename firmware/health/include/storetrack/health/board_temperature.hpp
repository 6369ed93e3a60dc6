// BoardTemperatureSampler: reads the board temperature (read_board_temp_cdeg) once per period
// on a thread of its own and publishes it to an atomic. sysfs thermal reads go through the
// sensor's driver (milliseconds for an SoC zone, far more for an I2C sensor behind hwmon), so
// they must never run on the capture loop, which only loads the atomic.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <string>
#include <thread>

namespace storetrack::health {

class BoardTemperatureSampler {
 public:
  /// Publishes to `out` (0.01 degC, INT16_MIN when there is no sensor) from `root`
  /// (read_board_temp_cdeg), first at start() and then every `period_ms`.
  BoardTemperatureSampler(std::string root, int period_ms, std::atomic<std::int16_t>& out);
  ~BoardTemperatureSampler();
  BoardTemperatureSampler(const BoardTemperatureSampler&) = delete;
  BoardTemperatureSampler& operator=(const BoardTemperatureSampler&) = delete;

  void start();
  /// Waits for a read in progress.
  void stop();
  /// Reads completed so far.
  std::uint64_t samples() const { return samples_.load(std::memory_order_relaxed); }

 private:
  void run();

  std::string root_;
  int period_ms_;
  std::atomic<std::int16_t>& out_;
  std::atomic<std::uint64_t> samples_{0};
  std::mutex wake_mutex_;
  std::condition_variable wake_;
  bool stopping_ = false;
  std::thread thread_;
};

}  // namespace storetrack::health
