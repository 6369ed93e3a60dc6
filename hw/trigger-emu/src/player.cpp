#include "storetrack/trigger_emu/player.hpp"

#include <cerrno>
#include <ctime>

#include "storetrack/time/time.hpp"

namespace storetrack::trigger_emu {
namespace {

// Returns false when `stop` was raised while waiting.
bool sleep_until(std::int64_t mono_ns, const std::atomic<bool>& stop) {
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(mono_ns / time::kNsPerSecond);
  ts.tv_nsec = static_cast<long>(mono_ns % time::kNsPerSecond);
  while (!stop.load(std::memory_order_relaxed)) {
    const int rc = clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr);
    if (rc == 0) return true;
    if (rc != EINTR) return true;  // cannot sleep: write the edge now rather than never
  }
  return false;
}

}  // namespace

PlayResult play(LineDriver& driver, const std::vector<ScheduledPulse>& schedule,
                std::int64_t start_mono_ns, const std::atomic<bool>& stop) {
  PlayResult result;
  result.log.reserve(schedule.size());
  for (const ScheduledPulse& pulse : schedule) {
    SentPulse sent{pulse, start_mono_ns + pulse.rise_offset_ns, 0, 0};
    if (!pulse.sent()) {
      result.log.push_back(sent);
      continue;
    }
    if (!sleep_until(sent.planned_rise_mono_ns, stop)) {
      result.interrupted = true;
      break;
    }
    if (const int rc = driver.set(1); rc != 0) {
      result.error = rc;
      break;
    }
    sent.rise_mono_ns = time::monotonic_now_ns();
    // Width is measured from the actual rising edge: a late rise must not shorten the pulse.
    sleep_until(sent.rise_mono_ns + pulse.width_ns, stop);
    if (const int rc = driver.set(0); rc != 0) {
      result.error = rc;
      break;
    }
    sent.fall_mono_ns = time::monotonic_now_ns();
    result.log.push_back(sent);
  }
  driver.set(0);
  return result;
}

Lateness lateness(const std::vector<SentPulse>& log) {
  Lateness l;
  double sum = 0.0;
  for (const SentPulse& s : log) {
    if (!s.pulse.sent()) continue;
    const std::int64_t late = s.rise_mono_ns - s.planned_rise_mono_ns;
    sum += static_cast<double>(late);
    if (late > l.max_ns || l.sent == 0) l.max_ns = late;
    ++l.sent;
  }
  if (l.sent > 0) l.mean_ns = sum / l.sent;
  return l;
}

}  // namespace storetrack::trigger_emu
