#include "health/health_report.hpp"

#include <algorithm>

namespace storetrack::unit {
namespace {

std::uint32_t clamp_u32(std::uint64_t v) {
  return static_cast<std::uint32_t>(v & 0xFFFFFFFFu);
}

}  // namespace

void StatusLatches::clear_if_reported(std::uint16_t bit, bool& reported, bool may_clear) {
  if (may_clear && reported)
    counters_.status.fetch_and(static_cast<std::uint16_t>(~bit), std::memory_order_relaxed);
  reported = true;
}

void StatusLatches::reported(bool camera_up) {
  clear_if_reported(msg::unit_status::kCameraError, camera_reported_, camera_up);
  clear_if_reported(msg::unit_status::kTriggerError, trigger_reported_, true);
  // A refused frame: the next report carries it, one after it clears.
  clear_if_reported(msg::unit_status::kCentroidError, centroid_reported_, true);
}

msg::UnitHealth health_message(const HealthHeader& header, health::UnitCounters& counters) {
  msg::UnitHealth h{};
  h.unit_id = header.unit_id;
  h.clock_state = header.clock_state;
  h.uptime_s = header.uptime_s;
  h.report_tai_ns = header.report_tai_ns;
  h.ptp_offset_ns = counters.ptp_offset_ns.load();
  h.sensor_temp_cdeg = counters.sensor_temp_cdeg.load();
  h.board_temp_cdeg = counters.board_temp_cdeg.load();
  h.frames_captured = clamp_u32(counters.frames_captured.load());
  h.frames_dropped = clamp_u32(counters.frames_dropped.load());
  h.triggers_seen = clamp_u32(counters.triggers_seen.load());
  h.triggers_missing = clamp_u32(counters.triggers_missing.load());
  h.triggers_extra = clamp_u32(counters.triggers_extra.load());
  h.observations_sent = clamp_u32(counters.observations_sent.load());
  h.link_tx_errors = clamp_u32(counters.link_tx_errors.load());
  h.link_tx_dropped = clamp_u32(counters.link_tx_dropped.load());
  h.can_bus_off_count = static_cast<std::uint16_t>(counters.can_bus_off_count.load());
  h.can_error_frames = static_cast<std::uint16_t>(counters.can_error_frames.load());
  h.centroid_time_us_max = static_cast<std::uint16_t>(
      std::min<std::uint32_t>(counters.centroid_time_us_max.exchange(0), 0xFFFE));
  h.status = counters.status.load();
  return h;
}

}  // namespace storetrack::unit
