// GPIO trigger lines through libgpiod 1.6 (the character-device ABI: /dev/gpiochipN).
//
// Master: a generator thread drives the output line(s) high at t_k = t0 + k * period on
// CLOCK_MONOTONIC (clock_nanosleep TIMER_ABSTIME, so the schedule never drifts however late a
// single wake-up is) and low again pulse_width later; t0 is a whole multiple of the period
// (phase-locked to the unit clock). A wake-up later than max_late_ns skips that pulse (and any
// whole periods missed; counted as overruns) rather than driving it off the grid or bunching
// pulses: every unit pairs edges to the grid within a phase tolerance (frame_pairer.hpp), and a
// pulse driven later than that would be an exposure no unit can number. Each pulse's time stamp
// (taken around the set-value call) goes through a lock-free single-producer/single-consumer ring
// to read_edges(). Slave: the input line is requested for rising-edge events; each event carries
// the kernel's time stamp (CLOCK_MONOTONIC for the v1 ABI since Linux 5.7), which is the edge time
// used.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "storetrack/trigger/trigger_line.hpp"

struct gpiod_chip;
struct gpiod_line;

namespace storetrack::trigger {

struct GpioMasterConfig {
  std::string chip = "/dev/gpiochip0";  ///< path or name (gpiochip0) or label
  std::vector<unsigned> lines{0};       ///< output lines (one per camera, or one shared)
  double rate_hz = 100.0;               ///< 0 < rate <= 400
  std::int64_t pulse_width_ns = 100'000;
  bool active_low = false;
  bool realtime_priority = true;  ///< try SCHED_FIFO for the generator (ignored if refused)
  std::string consumer = "storetrack-unit";
  /// The latest a pulse may be driven after its grid time; later, it is skipped (an overrun).
  /// 0: period / 8, half the pairer's default phase tolerance (period / 4). In [0, period / 2).
  std::int64_t max_late_ns = 0;
};

struct GpioSlaveConfig {
  std::string chip = "/dev/gpiochip0";
  unsigned line = 0;
  bool active_low = false;
  std::string consumer = "storetrack-unit";
};

/// Returns 0 or -EINVAL with a reason.
int validate(const GpioMasterConfig& config, std::string* why = nullptr);

class GpioMasterTrigger final : public TriggerLine {
 public:
  explicit GpioMasterTrigger(GpioMasterConfig config);
  ~GpioMasterTrigger() override;
  GpioMasterTrigger(const GpioMasterTrigger&) = delete;
  GpioMasterTrigger& operator=(const GpioMasterTrigger&) = delete;

  int start() override;
  int stop() override;
  int read_edges(std::span<TriggerEdge> out, int timeout_ms) override;
  bool is_master() const override { return true; }
  TriggerLineStats stats() const override;
  const char* name() const override { return name_.c_str(); }
  /// Last error text (after a failing start()).
  const std::string& error() const { return error_; }

 private:
  void run();
  int request_lines();
  void release_lines();
  bool drive(int value);

  GpioMasterConfig config_;
  std::string name_;
  std::string error_;
  gpiod_chip* chip_ = nullptr;
  std::vector<gpiod_line*> lines_;
  std::thread thread_;
  std::atomic<bool> running_{false};
  // SPSC ring: generator thread writes, read_edges() reads.
  static constexpr std::size_t kRing = 1024;
  std::array<TriggerEdge, kRing> ring_{};
  std::atomic<std::uint64_t> write_index_{0};
  std::atomic<std::uint64_t> read_index_{0};
  std::atomic<std::uint64_t> edges_{0};
  std::atomic<std::uint64_t> overruns_{0};
  std::atomic<std::int64_t> max_late_ns_{0};
  std::atomic<std::uint64_t> dropped_{0};
  std::atomic<std::uint64_t> line_errors_{0};
  std::atomic<std::uint64_t> reopens_{0};
};

class GpioSlaveTrigger final : public TriggerLine {
 public:
  explicit GpioSlaveTrigger(GpioSlaveConfig config);
  ~GpioSlaveTrigger() override;
  GpioSlaveTrigger(const GpioSlaveTrigger&) = delete;
  GpioSlaveTrigger& operator=(const GpioSlaveTrigger&) = delete;

  int start() override;
  int stop() override;
  int read_edges(std::span<TriggerEdge> out, int timeout_ms) override;
  bool is_master() const override { return false; }
  TriggerLineStats stats() const override { return stats_; }
  const char* name() const override { return name_.c_str(); }
  const std::string& error() const { return error_; }

 private:
  int request_line();
  void release_line();
  int line_error();
  int reopen_if_due(int timeout_ms);
  GpioSlaveConfig config_;
  std::string name_;
  std::string error_;
  gpiod_chip* chip_ = nullptr;
  gpiod_line* line_ = nullptr;
  std::uint32_t line_count_ = 0;
  int consecutive_errors_ = 0;
  bool wanted_ = false;  // start() called and not stop()ped: keep the line requested
  std::int64_t reopen_due_ns_ = 0;
  TriggerLineStats stats_;
};

}  // namespace storetrack::trigger
