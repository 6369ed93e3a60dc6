// UnitRegisters: the unit's settings as Modbus holding registers (docs/modbus.md), the Modbus
// TCP server that serves them with the health counters, and what an operator wrote to them in
// maintenance mode, decoded into settings once per write.
#pragma once

#include <cstdint>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <string>

#include "storetrack/health/modbus_server.hpp"
#include "storetrack/health/unit_state.hpp"
#include "unit_config.hpp"

namespace storetrack::unit {

/// The settings the holding registers hold, as the unit reads them.
struct RegisterSettings {
  int threshold_dn = 0;
  std::uint32_t exposure_us = 0;
  double trigger_rate_hz = 0;
  std::int64_t pulse_width_ns = 0;
  int roi_x = 0;
  int roi_y = 0;
  int roi_width = 0;
  int roi_height = 0;
};

class UnitRegisters {
 public:
  /// The registers from the configuration; the ids locked (they change only at a restart) and
  /// the search region limited to the frame.
  void load(const UnitConfig& config, int frame_width, int frame_height);
  /// modbus_enabled: serves the registers and `counters`. Returns false with `error`.
  bool start_server(const UnitConfig& config, health::UnitCounters& counters, std::string& error);
  void stop();
  /// True once after each accepted write, with the settings of one snapshot (a multi-register
  /// write, rate and pulse width or the search region, is seen whole). `config` gives the
  /// pulse width the register can only show clamped.
  bool take_changes(const UnitConfig& config, RegisterSettings& out);
  /// Shows the exposure the camera has (a change refused or clamped by the driver).
  void show_exposure(std::uint32_t exposure_us);
  /// The "modbus" block of the stats (when serving).
  void add_stats(nlohmann::json& stats) const;

 private:
  health::ConfigStore store_;
  std::unique_ptr<health::ModbusHealthServer> server_;  // reads store_: declared after it
  std::uint32_t seen_generation_ = 0;
};

}  // namespace storetrack::unit
