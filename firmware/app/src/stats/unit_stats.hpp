// The unit's statistics at exit (--stats-json): the loop's counters and each part's own block,
// and the verdict of a paced simulated source on real time.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "clock/unit_clock.hpp"
#include "input/camera.hpp"
#include "input/trigger.hpp"
#include "links/link_set.hpp"
#include "marks/mark_finder.hpp"
#include "modbus/unit_registers.hpp"
#include "pairing/trigger_pairing.hpp"
#include "recovery/camera_recovery.hpp"
#include "simulated_camera.hpp"
#include "stats/run_counters.hpp"
#include "storetrack/health/unit_state.hpp"
#include "unit_config.hpp"

namespace storetrack::unit {

/// What the statistics read: the loop's counters and its parts (camera and trigger null when
/// not configured).
struct UnitStatsSources {
  const UnitConfig& config;
  const RunCounters& run;
  const health::UnitCounters& counters;
  double duration_s;
  const Camera* camera;
  const CameraRecoveryCounters& recovery;
  const Trigger* trigger;
  const TriggerPairing& pairing;
  const MarkFinder& marks;
  const UnitClock& clock;
  const LinkSet& links;
  const UnitRegisters& registers;
};

/// The statistics as indented JSON, with a final newline.
std::string unit_stats_json(const UnitStatsSources& sources, const std::string& exit_reason,
                            int exit_code);

/// A paced simulated source: whether it kept its schedule ("real time kept ...") or by how much
/// it fell behind ("NOT real time ..."); empty when the source is not paced.
std::string realtime_verdict(const std::optional<SimulatedPacing>& pacing, std::uint64_t frames);

}  // namespace storetrack::unit
