#include "links/link_set.hpp"

#include <algorithm>
#include <nlohmann/json.hpp>

#include "storetrack/link/canfd_link.hpp"
#include "storetrack/link/udp_link.hpp"

namespace storetrack::unit {

bool LinkSet::open(const UnitConfig& config, std::string& error) {
  for (const auto& u : config.udp)
    links_.push_back(std::make_unique<link::UdpLink>(u));
  for (const auto& c : config.canfd)
    links_.push_back(std::make_unique<link::CanFdLink>(c));
  for (auto& l : links_) {
    if (l->open() < 0) {
      error = std::string("link: ") + l->error();
      return false;
    }
  }
  return true;
}

void LinkSet::close() {
  for (auto& l : links_)
    l->close();
}

bool LinkSet::send(const msg::MarkObservations& observations) {
  bool sent_any = links_.empty();
  for (auto& l : links_) {
    if (l->send(observations) == 0) sent_any = true;
  }
  return sent_any;
}

void LinkSet::send(const msg::UnitHealth& health) {
  for (auto& l : links_)
    l->send(health);
}

void LinkSet::service(health::UnitCounters& counters) {
  std::uint64_t sent = 0, errors = 0, dropped = 0, bus_off = 0, error_frames = 0;
  bool any_bus_off = false;
  for (const auto& l : links_) {
    l->service();
    const link::LinkStats s = l->stats();
    sent = std::max(sent, s.observations_sent);
    errors += s.tx_errors + s.encode_errors;
    dropped += s.dropped_exposures;
    bus_off += s.bus_off_events;
    error_frames += s.error_frames;
    any_bus_off = any_bus_off || s.bus_off;
  }
  counters.observations_sent.store(sent, std::memory_order_relaxed);
  counters.link_tx_errors.store(errors, std::memory_order_relaxed);
  counters.link_tx_dropped.store(dropped, std::memory_order_relaxed);
  counters.can_bus_off_count.store(bus_off, std::memory_order_relaxed);
  counters.can_error_frames.store(error_frames, std::memory_order_relaxed);
  std::uint16_t status = counters.status.load(std::memory_order_relaxed);
  status = any_bus_off ? status | msg::unit_status::kCanBusOff
                       : status & static_cast<std::uint16_t>(~msg::unit_status::kCanBusOff);
  counters.status.store(status, std::memory_order_relaxed);
}

void LinkSet::add_stats(nlohmann::json& stats) const {
  nlohmann::json links = nlohmann::json::array();
  for (const auto& l : links_) {
    const link::LinkStats s = l->stats();
    links.push_back({{"name", l->name()},
                     {"observations_sent", s.observations_sent},
                     {"health_sent", s.health_sent},
                     {"tx_errors", s.tx_errors},
                     {"dropped_exposures", s.dropped_exposures},
                     {"partial_exposures", s.partial_exposures},
                     {"encode_errors", s.encode_errors},
                     {"bus_off_events", s.bus_off_events},
                     {"error_frames", s.error_frames},
                     {"bus_off", s.bus_off},
                     {"link_down", s.link_down},
                     {"last_errno", s.last_errno}});
  }
  stats["links"] = links;
}

}  // namespace storetrack::unit
