// Pulse schedule of the bench trigger emulator (storetrack-trigger-emu): the FTI system's camera
// trigger as the unit sees it on its input line, with the faults a bench test must detect.
// Pure logic (no I/O): the same schedule drives a real GPIO chip, gpio-sim, and the unit tests.
#pragma once

#include <cstdint>
#include <iosfwd>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

namespace storetrack::trigger_emu {

enum class FaultKind : std::uint8_t {
  kMissing,  ///< the nominal pulse is not sent
  kDouble,   ///< one extra pulse `gap_ns` after the nominal pulse's rising edge
  kBurst,    ///< `count` extra pulses, `gap_ns` apart, after the nominal pulse
};

struct Fault {
  FaultKind kind = FaultKind::kMissing;
  int at_index = 0;         ///< nominal pulse index (0-based) the fault applies to
  int count = 1;            ///< extra pulses (kBurst; kDouble is always 1)
  std::int64_t gap_ns = 0;  ///< rising edge to rising edge of the extra pulses; 0 = 2 x width
};

struct ScheduleConfig {
  double rate_hz = 50.0;  ///< nominal trigger rate
  std::int64_t pulse_width_ns = 1'000'000;
  std::int64_t jitter_ns = 0;  ///< rising edges uniformly in [-jitter, +jitter] of nominal
  int count = 100;             ///< nominal pulses (including the ones a fault removes)
  std::uint64_t seed = 1;      ///< jitter draws (std::mt19937_64)
  std::vector<Fault> faults;
};

enum class PulseKind : std::uint8_t { kNominal, kMissing, kDouble, kBurst };

const char* to_string(PulseKind kind);
const char* to_string(FaultKind kind);

/// One row of the schedule. kMissing rows are NOT sent; they are kept so the log tells the bench
/// test which nominal pulse was withheld.
struct ScheduledPulse {
  std::int64_t rise_offset_ns = 0;  ///< rising edge, relative to the schedule start
  std::int64_t width_ns = 0;
  int nominal_index = 0;  ///< nominal pulse this row belongs to
  PulseKind kind = PulseKind::kNominal;
  bool sent() const { return kind != PulseKind::kMissing; }
};

/// Nominal period in ns, rounded to the nearest ns.
std::int64_t period_ns(const ScheduleConfig& config);

/// Validates the configuration (throws std::invalid_argument with the reason): rate > 0,
/// 0 < width, width + 2 jitter < period, faults inside [0, count), extra pulses neither overlap
/// each other nor the next nominal pulse's earliest possible rising edge, one fault per index.
void validate(const ScheduleConfig& config);

/// All pulses in time order (kMissing rows at their nominal time). Deterministic for a seed.
std::vector<ScheduledPulse> make_schedule(const ScheduleConfig& config);

/// Faults from a JSON script: {"faults": [{"kind": "missing"|"double"|"burst", "at": 10,
/// "count": 5, "gap_us": 300}, ...]}. Throws nlohmann::json::exception / std::invalid_argument.
std::vector<Fault> parse_fault_script(const nlohmann::json& script);

/// What was actually sent: a scheduled pulse plus the CLOCK_MONOTONIC times the emulator read
/// right after writing each edge (0 for kMissing rows).
struct SentPulse {
  ScheduledPulse pulse;
  std::int64_t planned_rise_mono_ns = 0;
  std::int64_t rise_mono_ns = 0;
  std::int64_t fall_mono_ns = 0;
};

/// CSV: header `seq,nominal_index,kind,planned_rise_mono_ns,rise_mono_ns,fall_mono_ns,width_ns`.
void write_log_csv(std::ostream& out, const std::vector<SentPulse>& log);
/// JSON: {"clock": "CLOCK_MONOTONIC", "config": {...}, "pulses": [{...same fields...}]}.
nlohmann::json log_to_json(const ScheduleConfig& config, const std::vector<SentPulse>& log);

}  // namespace storetrack::trigger_emu
