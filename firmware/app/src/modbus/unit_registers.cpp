#include "modbus/unit_registers.hpp"

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

namespace storetrack::unit {
namespace {

using health::HoldingField;

/// The pulse_width_us register's view of a pulse width (docs/modbus.md: 1..5000 us).
std::uint16_t pulse_width_register(std::int64_t width_ns) {
  return static_cast<std::uint16_t>(std::clamp<std::int64_t>(width_ns / 1000, 1, 5000));
}

}  // namespace

void UnitRegisters::load(const UnitConfig& config, int frame_width, int frame_height) {
  store_.set(HoldingField::kUnitId, static_cast<std::uint16_t>(config.unit_id));
  store_.set(HoldingField::kCameraId, static_cast<std::uint16_t>(config.camera_id));
  store_.set(HoldingField::kExposureUs, static_cast<std::uint16_t>(config.exposure_us));
  store_.set(HoldingField::kTriggerRateHz,
             static_cast<std::uint16_t>(std::lround(std::min(config.trigger.rate_hz, 400.0))));
  store_.set(HoldingField::kPulseWidthUs, pulse_width_register(config.trigger.pulse_width_ns));
  store_.set(HoldingField::kThresholdDn,
             static_cast<std::uint16_t>(std::clamp(config.centroid.threshold_dn, 0, 65535)));
  store_.set(HoldingField::kRoiX, static_cast<std::uint16_t>(config.roi_x));
  store_.set(HoldingField::kRoiY, static_cast<std::uint16_t>(config.roi_y));
  store_.set(HoldingField::kRoiWidth, static_cast<std::uint16_t>(config.roi_width));
  store_.set(HoldingField::kRoiHeight, static_cast<std::uint16_t>(config.roi_height));
  seen_generation_ = store_.generation();
  store_.lock_identity();  // ids change only at a restart (docs/modbus.md)
  store_.set_limits({frame_width, frame_height});
}

bool UnitRegisters::start_server(const UnitConfig& config, health::UnitCounters& counters,
                                 std::string& error) {
  if (!config.modbus_enabled) return true;
  health::ModbusServerConfig mc;
  mc.address = config.modbus_address;
  mc.port = config.modbus_port;
  mc.maintenance = config.maintenance;
  server_ = std::make_unique<health::ModbusHealthServer>(mc, counters, store_);
  if (server_->start() < 0) {
    error = server_->error();
    return false;
  }
  return true;
}

void UnitRegisters::stop() {
  if (server_) server_->stop();
}

bool UnitRegisters::take_changes(const UnitConfig& config, RegisterSettings& out) {
  const std::uint32_t gen = store_.generation();
  if (gen == seen_generation_) return false;
  seen_generation_ = gen;
  const health::ConfigStore::Values v = store_.snapshot();
  const auto get = [&v](HoldingField f) { return v[static_cast<std::size_t>(f)]; };
  out.threshold_dn = get(HoldingField::kThresholdDn);
  out.exposure_us = get(HoldingField::kExposureUs);
  out.trigger_rate_hz = get(HoldingField::kTriggerRateHz);
  // The width register holds at most 5000 us: while it still shows the configured width (a
  // longer one clamped), the configured width stands; a rate write must not shorten it.
  const std::uint16_t width_us = get(HoldingField::kPulseWidthUs);
  out.pulse_width_ns = width_us == pulse_width_register(config.trigger.pulse_width_ns)
                           ? config.trigger.pulse_width_ns
                           : std::int64_t{width_us} * 1000;
  out.roi_x = get(HoldingField::kRoiX);
  out.roi_y = get(HoldingField::kRoiY);
  out.roi_width = get(HoldingField::kRoiWidth);
  out.roi_height = get(HoldingField::kRoiHeight);
  return true;
}

void UnitRegisters::show_exposure(std::uint32_t exposure_us) {
  store_.set(HoldingField::kExposureUs, static_cast<std::uint16_t>(exposure_us));
}

void UnitRegisters::add_stats(nlohmann::json& stats) const {
  if (!server_) return;
  const health::ModbusServerStats ms = server_->stats();
  stats["modbus"] = {{"port", server_->bound_port()},
                     {"requests", ms.requests},
                     {"refused_function", ms.refused_function},
                     {"refused_write_locked", ms.refused_write_locked},
                     {"refused_value", ms.refused_value},
                     {"malformed", ms.malformed},
                     {"writes_accepted", ms.writes_accepted},
                     {"refused_identity", ms.refused_identity},
                     {"connections", ms.connections},
                     {"evicted", ms.evicted},
                     {"timeouts", ms.timeouts},
                     {"idle_closed", ms.idle_closed}};
}

}  // namespace storetrack::unit
