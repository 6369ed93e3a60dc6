// ClockMonitor: polls ptp4l (PORT_DATA_SET, TIME_STATUS_NP, TIME_PROPERTIES_DATA_SET) once per
// period on a thread of its own, runs the LockStateMachine and publishes the state, the offset
// from the master and the clock's uncertainty figure (clock_uncertainty.hpp) as atomics. The
// capture loop only loads them (relaxed, no lock, no system call), so a slow or absent ptp4l can
// never delay a frame.
#pragma once

#include <array>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <string>
#include <thread>

#include "storetrack/clock/clock_uncertainty.hpp"
#include "storetrack/clock/lock_state.hpp"
#include "storetrack/clock/ptp4l_client.hpp"

namespace storetrack::clock {

struct ClockMonitorConfig {
  Ptp4lClientConfig ptp4l;
  LockThresholds lock;
  ClockUncertaintyConfig uncertainty;
  int poll_period_ms = 1000;  ///< the unit's health period
};

/// What the last poll saw and how the monitor got there (stats JSON, tests).
struct ClockMonitorStats {
  std::uint64_t polls = 0;
  std::uint64_t answered_polls = 0;  ///< polls where PORT_DATA_SET and TIME_STATUS_NP replied
  std::uint64_t transitions = 0;     ///< state changes
  PortState port_state = PortState::kUnknown;
  bool gm_present = false;
  bool time_traceable = false;
  std::int64_t master_offset_ns = 0;  ///< last reported by ptp4l (also when not tracking)
  std::int64_t ingress_time_ns = 0;   ///< of the Sync behind master_offset_ns (0: none yet)
  std::uint64_t new_offsets = 0;      ///< new measurements taken into the uncertainty's window
  double offset_rms_ns = 0;           ///< their RMS over the window (ClockFigure::rms_ns)
  std::array<std::uint8_t, 8> gm_identity{};
  Ptp4lClientStats client{};
};

class ClockMonitor {
 public:
  explicit ClockMonitor(ClockMonitorConfig config);
  ~ClockMonitor();
  ClockMonitor(const ClockMonitor&) = delete;
  ClockMonitor& operator=(const ClockMonitor&) = delete;

  /// Opens the client socket (0 or -errno, error() says why) and, with `thread`, starts
  /// polling every poll_period_ms. ptp4l need not run yet: until it answers, FREE_RUNNING.
  int start(bool thread = true);
  void stop();
  /// One poll now (the thread's body; tests call it directly with start(false)).
  time::ClockState poll_once();

  time::ClockState state() const {
    return static_cast<time::ClockState>(state_.load(std::memory_order_relaxed));
  }
  std::int32_t offset_ns() const { return offset_ns_.load(std::memory_order_relaxed); }
  /// The uncertainty figure of the last poll (three loads; a poll between them mixes two
  /// consecutive polls' figures, which differ by one poll's growth at most).
  ClockFigure figure() const {
    ClockFigure f;
    f.holding = holding_.load(std::memory_order_acquire);
    f.rms_ns = rms_ns_.load(std::memory_order_relaxed);
    f.measured_at_ns = measured_at_ns_.load(std::memory_order_relaxed);
    return f;
  }
  ClockMonitorStats stats() const;
  const std::string& error() const { return client_.error(); }
  const ClockMonitorConfig& config() const { return config_; }

 private:
  PtpPoll query();
  void run();

  ClockMonitorConfig config_;
  Ptp4lClient client_;
  LockStateMachine machine_;
  OffsetWindow window_;
  std::atomic<std::uint8_t> state_{static_cast<std::uint8_t>(time::ClockState::kFreeRunning)};
  std::atomic<std::int32_t> offset_ns_{kOffsetUnknown};
  std::atomic<double> rms_ns_{0};
  std::atomic<time::MonotonicNs> measured_at_ns_{0};
  std::atomic<bool> holding_{false};
  mutable std::mutex stats_mutex_;  // the thread and stats() only, never the capture loop
  ClockMonitorStats stats_;
  std::mutex wake_mutex_;
  std::condition_variable wake_;
  bool stopping_ = false;
  std::thread thread_;
};

}  // namespace storetrack::clock
