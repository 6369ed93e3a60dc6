// The capture loop's own counters, for the stats JSON (--stats-json). The counters the host
// and Modbus see live in health::UnitCounters; each part counts its own (links, pairing, ...).
#pragma once

#include <cstdint>

namespace storetrack::unit {

struct RunCounters {
  std::uint64_t frames = 0;
  std::uint64_t frames_processed = 0;
  std::uint64_t marks = 0;
  std::uint64_t centroid_errors = 0;
  std::uint64_t source_errors = 0;
  std::uint64_t health_sent = 0;
  std::uint64_t skipped_no_marks = 0;          ///< triggered_only: frames without marks, not paired
  std::uint64_t skipped_untriggered = 0;       ///< triggered_only: frames no edge claimed, not sent
  std::uint64_t frames_corrupt = 0;            ///< frames the camera gave back as bad (-EBADMSG)
  std::uint64_t release_errors = 0;            ///< a frame could not be given back to the source
  std::uint64_t config_apply_errors = 0;       ///< Modbus changes the unit could not apply
  std::uint64_t trigger_errors = 0;            ///< failed edge reads + pulses not driven
  std::uint64_t trigger_restart_failures = 0;  ///< ... and the previous trigger not restarted
  std::uint64_t trigger_restarts = 0;  ///< a trigger that could not be restarted running again
  double centroid_us_sum = 0;
  double centroid_us_max = 0;
};

}  // namespace storetrack::unit
