#include "storetrack/trigger_emu/schedule.hpp"

#include <algorithm>
#include <cmath>
#include <ostream>
#include <random>
#include <set>
#include <stdexcept>
#include <string>

#include <nlohmann/json.hpp>

namespace storetrack::trigger_emu {
namespace {

std::int64_t effective_gap_ns(const ScheduleConfig& config, const Fault& fault) {
  return fault.gap_ns > 0 ? fault.gap_ns : 2 * config.pulse_width_ns;
}

int extra_pulses(const Fault& fault) {
  switch (fault.kind) {
    case FaultKind::kMissing:
      return 0;
    case FaultKind::kDouble:
      return 1;
    case FaultKind::kBurst:
      return fault.count;
  }
  return 0;
}

[[noreturn]] void invalid(const std::string& what) {
  throw std::invalid_argument("trigger schedule: " + what);
}

}  // namespace

const char* to_string(PulseKind kind) {
  switch (kind) {
    case PulseKind::kNominal:
      return "nominal";
    case PulseKind::kMissing:
      return "missing";
    case PulseKind::kDouble:
      return "double";
    case PulseKind::kBurst:
      return "burst";
  }
  return "unknown";
}

const char* to_string(FaultKind kind) {
  switch (kind) {
    case FaultKind::kMissing:
      return "missing";
    case FaultKind::kDouble:
      return "double";
    case FaultKind::kBurst:
      return "burst";
  }
  return "unknown";
}

std::int64_t period_ns(const ScheduleConfig& config) {
  return std::llround(1e9 / config.rate_hz);
}

void validate(const ScheduleConfig& config) {
  if (!(config.rate_hz > 0.0) || !std::isfinite(config.rate_hz) || config.rate_hz > 1e6) {
    invalid("rate must be in (0, 1 MHz], got " + std::to_string(config.rate_hz));
  }
  if (config.count < 0) invalid("count must be >= 0");
  if (config.pulse_width_ns <= 0) invalid("pulse width must be > 0");
  if (config.jitter_ns < 0) invalid("jitter must be >= 0");
  const std::int64_t period = period_ns(config);
  if (config.pulse_width_ns + 2 * config.jitter_ns >= period) {
    invalid("pulse width + 2 x jitter (" +
            std::to_string(config.pulse_width_ns + 2 * config.jitter_ns) +
            " ns) must be shorter than the period (" + std::to_string(period) + " ns)");
  }
  std::set<int> indices;
  for (const Fault& fault : config.faults) {
    if (fault.at_index < 0 || fault.at_index >= config.count) {
      invalid(std::string(to_string(fault.kind)) + " fault at pulse " +
              std::to_string(fault.at_index) + " is outside [0, " + std::to_string(config.count) +
              ")");
    }
    if (!indices.insert(fault.at_index).second) {
      invalid("more than one fault at pulse " + std::to_string(fault.at_index));
    }
    if (fault.kind == FaultKind::kBurst && fault.count < 1) invalid("burst count must be >= 1");
    if (fault.kind == FaultKind::kMissing) continue;
    const std::int64_t gap = effective_gap_ns(config, fault);
    if (gap <= config.pulse_width_ns) {
      invalid("extra pulses at " + std::to_string(fault.at_index) + ": gap " + std::to_string(gap) +
              " ns must exceed the pulse width (edges would merge)");
    }
    // Worst case: this pulse jittered late, the next one jittered early.
    const std::int64_t last_fall =
        config.jitter_ns + extra_pulses(fault) * gap + config.pulse_width_ns;
    if (last_fall >= period - config.jitter_ns) {
      invalid("extra pulses at " + std::to_string(fault.at_index) +
              " run into the next nominal pulse");
    }
  }
}

std::vector<ScheduledPulse> make_schedule(const ScheduleConfig& config) {
  validate(config);
  const std::int64_t period = period_ns(config);
  std::mt19937_64 rng(config.seed);
  std::uniform_int_distribution<std::int64_t> jitter(-config.jitter_ns, config.jitter_ns);

  std::vector<const Fault*> fault_at(static_cast<std::size_t>(config.count), nullptr);
  for (const Fault& fault : config.faults)
    fault_at[static_cast<std::size_t>(fault.at_index)] = &fault;

  std::vector<ScheduledPulse> out;
  out.reserve(static_cast<std::size_t>(config.count) + 16);
  for (int i = 0; i < config.count; ++i) {
    // One draw per nominal pulse, sent or not, so a fault does not shift later pulses' jitter.
    const std::int64_t rise =
        static_cast<std::int64_t>(i) * period + (config.jitter_ns > 0 ? jitter(rng) : 0);
    const Fault* fault = fault_at[static_cast<std::size_t>(i)];
    ScheduledPulse nominal{rise, config.pulse_width_ns, i, PulseKind::kNominal};
    if (fault != nullptr && fault->kind == FaultKind::kMissing) nominal.kind = PulseKind::kMissing;
    out.push_back(nominal);
    if (fault == nullptr || fault->kind == FaultKind::kMissing) continue;
    const std::int64_t gap = effective_gap_ns(config, *fault);
    const PulseKind kind =
        fault->kind == FaultKind::kDouble ? PulseKind::kDouble : PulseKind::kBurst;
    for (int k = 1; k <= extra_pulses(*fault); ++k) {
      out.push_back({rise + k * gap, config.pulse_width_ns, i, kind});
    }
  }
  return out;
}

std::vector<Fault> parse_fault_script(const nlohmann::json& script) {
  std::vector<Fault> faults;
  for (const nlohmann::json& item : script.at("faults")) {
    Fault fault;
    const std::string kind = item.at("kind").get<std::string>();
    if (kind == "missing") {
      fault.kind = FaultKind::kMissing;
    } else if (kind == "double") {
      fault.kind = FaultKind::kDouble;
    } else if (kind == "burst") {
      fault.kind = FaultKind::kBurst;
    } else {
      throw std::invalid_argument("fault script: unknown kind '" + kind +
                                  "' (missing, double, burst)");
    }
    fault.at_index = item.at("at").get<int>();
    fault.count = item.value("count", 1);
    fault.gap_ns = std::llround(item.value("gap_us", 0.0) * 1e3);
    faults.push_back(fault);
  }
  return faults;
}

void write_log_csv(std::ostream& out, const std::vector<SentPulse>& log) {
  out << "seq,nominal_index,kind,planned_rise_mono_ns,rise_mono_ns,fall_mono_ns,width_ns\n";
  int seq = 0;
  for (const SentPulse& s : log) {
    out << (s.pulse.sent() ? seq++ : -1) << ',' << s.pulse.nominal_index << ','
        << to_string(s.pulse.kind) << ',' << s.planned_rise_mono_ns << ',' << s.rise_mono_ns << ','
        << s.fall_mono_ns << ',' << s.pulse.width_ns << '\n';
  }
}

nlohmann::json log_to_json(const ScheduleConfig& config, const std::vector<SentPulse>& log) {
  nlohmann::json faults = nlohmann::json::array();
  for (const Fault& f : config.faults) {
    faults.push_back({{"kind", to_string(f.kind)},
                      {"at", f.at_index},
                      {"count", f.count},
                      {"gap_us", static_cast<double>(f.gap_ns) * 1e-3}});
  }
  nlohmann::json pulses = nlohmann::json::array();
  int seq = 0;
  for (const SentPulse& s : log) {
    pulses.push_back({{"seq", s.pulse.sent() ? seq++ : -1},
                      {"nominal_index", s.pulse.nominal_index},
                      {"kind", to_string(s.pulse.kind)},
                      {"planned_rise_mono_ns", s.planned_rise_mono_ns},
                      {"rise_mono_ns", s.rise_mono_ns},
                      {"fall_mono_ns", s.fall_mono_ns},
                      {"width_ns", s.pulse.width_ns}});
  }
  return {{"clock", "CLOCK_MONOTONIC"},
          {"config",
           {{"rate_hz", config.rate_hz},
            {"pulse_width_ns", config.pulse_width_ns},
            {"jitter_ns", config.jitter_ns},
            {"count", config.count},
            {"seed", config.seed},
            {"faults", faults}}},
          {"pulses", pulses}};
}

}  // namespace storetrack::trigger_emu
