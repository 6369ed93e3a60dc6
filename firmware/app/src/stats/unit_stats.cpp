#include "stats/unit_stats.hpp"

#include <cstdio>
#include <nlohmann/json.hpp>

namespace storetrack::unit {

namespace {
// A unit that renders slower than its rate falls behind without bound; one that keeps up is
// late only by the scheduler's jitter (a few ms on a loaded 2-core machine).
constexpr std::int64_t kRealtimeToleranceNs = 100'000'000;
}  // namespace

std::string realtime_verdict(const std::optional<SimulatedPacing>& pacing, std::uint64_t frames) {
  if (!pacing) return "";
  const SimulatedPacing p = *pacing;
  char line[256];
  if (p.max_behind_ns <= kRealtimeToleranceNs) {
    std::snprintf(line, sizeof line,
                  "real time kept: at most %.1f ms behind the frame schedule (tolerance %.0f ms); "
                  "%lld frames more than one frame period (%.2f ms) late",
                  static_cast<double>(p.max_behind_ns) / 1e6, kRealtimeToleranceNs / 1e6,
                  static_cast<long long>(p.frames_late), p.frame_period_ns / 1e6);
  } else {
    std::snprintf(line, sizeof line,
                  "NOT real time: fell up to %.1f ms behind the frame schedule; %lld of %lld "
                  "frames more than one frame period (%.2f ms) late",
                  static_cast<double>(p.max_behind_ns) / 1e6, static_cast<long long>(p.frames_late),
                  static_cast<long long>(frames), p.frame_period_ns / 1e6);
  }
  return line;
}

std::string unit_stats_json(const UnitStatsSources& s, const std::string& exit_reason,
                            int exit_code) {
  const UnitConfig& config = s.config;
  const RunCounters& run = s.run;
  nlohmann::json j;
  j["exit_code"] = exit_code;
  j["exit_reason"] = exit_reason;
  j["source"] = to_string(config.source);
  j["trigger_mode"] = to_string(config.trigger.mode);
  j["unit_id"] = config.unit_id;
  j["camera_id"] = config.camera_id;
  j["duration_s"] = s.duration_s;
  j["frames_captured"] = run.frames;
  j["frames_processed"] = run.frames_processed;
  j["frames_dropped"] = s.counters.frames_dropped.load();
  j["source_errors"] = run.source_errors;
  j["camera"] = {{"failures", s.recovery.failures},
                 {"reopens", s.recovery.reopens},
                 {"reopen_failures", s.recovery.reopen_failures},
                 {"down_s", s.recovery.down_s},
                 {"frames_corrupt", run.frames_corrupt},
                 {"release_errors", run.release_errors}};
  if (s.camera) s.camera->add_stats(j["camera"], j);
  if (const std::optional<SimulatedPacing> pacing = s.camera ? s.camera->pacing() : std::nullopt) {
    const SimulatedPacing p = *pacing;
    j["sim_pacing"] = {{"max_behind_ms", static_cast<double>(p.max_behind_ns) / 1e6},
                       {"frames_late", p.frames_late},
                       {"frame_period_ms", p.frame_period_ns / 1e6},
                       {"realtime_kept", p.max_behind_ns <= kRealtimeToleranceNs}};
  }
  j["centroid_errors"] = run.centroid_errors;
  j["marks_total"] = run.marks;
  j["marks_per_frame_mean"] = run.frames_processed ? static_cast<double>(run.marks) /
                                                         static_cast<double>(run.frames_processed)
                                                   : 0.0;
  j["centroid_time_us_mean"] =
      run.frames_processed ? run.centroid_us_sum / static_cast<double>(run.frames_processed) : 0.0;
  j["centroid_time_us_max"] = run.centroid_us_max;
  j["health_sent"] = run.health_sent;
  j["edges_read"] = s.pairing.edges_read();
  if (config.trigger.triggered_only) {
    j["triggered_only"] = {{"skipped_no_marks", run.skipped_no_marks},
                           {"skipped_untriggered", run.skipped_untriggered}};
  }
  s.pairing.add_stats(j);
  if (s.trigger) {
    const trigger::TriggerLineStats ts = s.trigger->line().stats();
    j["trigger_line"] = {{"name", s.trigger->line().name()},
                         {"edges", ts.edges},
                         {"overruns", ts.overruns},
                         {"max_late_ns", ts.max_late_ns},
                         {"dropped_edges", ts.dropped_edges},
                         {"line_errors", ts.line_errors},
                         {"reopens", ts.reopens},
                         {"errors_reported", run.trigger_errors}};
  }
  s.marks.add_stats(j);
  s.clock.add_stats(j, config.clock_state, s.counters.ptp_offset_ns.load());
  s.links.add_stats(j);
  s.registers.add_stats(j);
  j["config_apply_errors"] = run.config_apply_errors;
  j["trigger_restart_failures"] = run.trigger_restart_failures;
  j["trigger_restarts"] = run.trigger_restarts;
  return j.dump(2) + "\n";
}

}  // namespace storetrack::unit
