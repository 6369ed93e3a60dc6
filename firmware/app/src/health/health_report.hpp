// The periodic UnitHealth report: the message from the shared counters (the Modbus server
// reads the same ones), and the status bits that must reach the host at least once.
#pragma once

#include <cstdint>

#include "storetrack/health/unit_state.hpp"
#include "storetrack/msg/messages.hpp"

namespace storetrack::unit {

/// The camera-, trigger- and centroid-error status bits: raised when the fault happens, held
/// until a health report carried them. A camera fault clears only once the camera is back.
class StatusLatches {
 public:
  explicit StatusLatches(health::UnitCounters& counters) : counters_(counters) {}
  void raise_camera_error() { raise(msg::unit_status::kCameraError, camera_reported_); }
  void raise_trigger_error() { raise(msg::unit_status::kTriggerError, trigger_reported_); }
  void raise_centroid_error() { raise(msg::unit_status::kCentroidError, centroid_reported_); }
  /// After a report was sent: the bits it carried are cleared, the camera's while `camera_up`.
  void reported(bool camera_up);

 private:
  void raise(std::uint16_t bit, bool& reported) {
    counters_.status.fetch_or(bit, std::memory_order_relaxed);
    reported = false;
  }
  void clear_if_reported(std::uint16_t bit, bool& reported, bool may_clear);

  health::UnitCounters& counters_;
  bool camera_reported_ = true;
  bool trigger_reported_ = true;
  bool centroid_reported_ = true;
};

/// What the report says beside the shared counters.
struct HealthHeader {
  std::uint8_t unit_id = 0;
  std::uint8_t clock_state = 0;
  std::uint32_t uptime_s = 0;
  std::int64_t report_tai_ns = 0;
};

/// The UnitHealth message; the centroid-time maximum starts again with each report.
msg::UnitHealth health_message(const HealthHeader& header, health::UnitCounters& counters);

}  // namespace storetrack::unit
