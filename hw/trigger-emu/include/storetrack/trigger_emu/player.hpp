// Plays a pulse schedule on a LineDriver against CLOCK_MONOTONIC (absolute sleeps, so lateness
// does not accumulate) and records when every edge was actually written.
#pragma once

#include <atomic>
#include <cstdint>
#include <vector>

#include "storetrack/trigger_emu/line_driver.hpp"
#include "storetrack/trigger_emu/schedule.hpp"

namespace storetrack::trigger_emu {

struct PlayResult {
  std::vector<SentPulse> log;  ///< one row per schedule row played (kMissing rows included)
  int error = 0;               ///< 0 or -errno of the first failed line write
  bool interrupted = false;    ///< `stop` was raised before the end
};

/// Plays `schedule` starting at CLOCK_MONOTONIC `start_mono_ns`. Leaves the lines deasserted.
PlayResult play(LineDriver& driver, const std::vector<ScheduledPulse>& schedule,
                std::int64_t start_mono_ns, const std::atomic<bool>& stop);

/// Lateness statistics of a played log (rise_mono_ns - planned_rise_mono_ns over sent pulses).
struct Lateness {
  int sent = 0;
  double mean_ns = 0.0;
  std::int64_t max_ns = 0;
};
Lateness lateness(const std::vector<SentPulse>& log);

}  // namespace storetrack::trigger_emu
