// LinkSet: every link the unit sends on (UDP, CAN FD), as one. An exposure counts as sent when
// any link took it; the links' counters are summed for the health report (observations_sent
// is the most any link sent: an exposure counts once, whatever the links).
#pragma once

#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

#include "storetrack/health/unit_state.hpp"
#include "storetrack/link/observation_link.hpp"
#include "storetrack/msg/messages.hpp"
#include "unit_config.hpp"

namespace storetrack::unit {

class LinkSet {
 public:
  /// Opens the configured links. Returns false with `error` naming the first that failed.
  bool open(const UnitConfig& config, std::string& error);
  void close();
  /// True when at least one link took the exposure, or there is no link to take it.
  bool send(const msg::MarkObservations& observations);
  void send(const msg::UnitHealth& health);
  /// Lets each link do its housekeeping (CAN bus-off recovery), then publishes their counters
  /// and the can_bus_off status bit.
  void service(health::UnitCounters& counters);
  /// The "links" array of the stats.
  void add_stats(nlohmann::json& stats) const;

 private:
  std::vector<std::unique_ptr<link::ObservationLink>> links_;
};

}  // namespace storetrack::unit
