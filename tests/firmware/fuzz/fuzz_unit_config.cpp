// libFuzzer target: the unit configuration reader (firmware/app parse_config_json, then
// validate, as storetrack-unit reads its --config file) on arbitrary text. Properties checked
// (abort when violated), beyond "no crash, no UB":
//  - a refusal is a ConfigError; no other exception escapes (a JSON type error, a number too
//    large for a double, a float too large for the integer it is read into);
//  - an accepted configuration holds the documented ranges (docs/unit-config.md): unit_id and
//    camera_id in [0, 254], exposure_us in [10, 20000], trigger.rate_hz in (0, 400], a pulse
//    shorter than 90 % of the period, modbus.port in [0, 65535];
//  - every value the file wrote is the value the unit runs with, read back through the
//    effective configuration (to_json, print-config): integers exactly (no 4294967296 read as
//    0, no 1.5 read as 1, no -1 as 4294967295), other numbers exactly but for the pulse width
//    (held in whole ns) and the ptp4l durations (whole ns), booleans and strings exactly; an
//    array the file wrote is an array the unit holds;
//  - the effective configuration reads back to itself (print-config output is a valid config).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include <nlohmann/json.hpp>

#include "unit_config.hpp"

namespace {

namespace unit = storetrack::unit;
using nlohmann::json;

void check_ranges(const unit::UnitConfig& c) {
  if (c.unit_id < 0 || c.unit_id > 254 || c.camera_id < 0 || c.camera_id > 254) std::abort();
  if (c.exposure_us < 10 || c.exposure_us > 20000) std::abort();
  if (!(c.trigger.rate_hz > 0 && c.trigger.rate_hz <= 400)) std::abort();
  if (!(c.trigger.pulse_width_ns > 0 &&
        static_cast<double>(c.trigger.pulse_width_ns) < 0.9e9 / c.trigger.rate_hz))
    std::abort();
  if (c.modbus_port < 0 || c.modbus_port > 65535) std::abort();
}

// How far the unit's value may be from the written one: the units it holds the value in.
double resolution(const std::string& key) {
  if (key == "pulse_width_us") return 0.5e-3;  // whole ns, rounded
  if (key == "holdover_s" || key == "offset_max_age_s") return 0.5e-9;
  return 0;
}

void check_as_written(const json& written, const json& effective, const std::string& key) {
  if (written.is_object() || written.is_array()) {
    if (written.is_object() != effective.is_object() || written.is_array() != effective.is_array())
      std::abort();
    if (written.is_array() && written.size() != effective.size()) std::abort();
    if (written.is_array()) {
      for (std::size_t i = 0; i < written.size(); ++i)
        check_as_written(written[i], effective[i], key);
      return;
    }
    for (const auto& [k, v] : written.items()) {
      if (!effective.contains(k)) std::abort();
      check_as_written(v, effective.at(k), k);
    }
    return;
  }
  if (written.is_null()) return;
  if (written.is_number_integer() && effective.is_number_integer()) {
    if (written != effective) std::abort();  // nlohmann compares signed and unsigned by value
    return;
  }
  if (written.is_number() && effective.is_number()) {
    if (effective.is_number_integer() && !written.is_number_integer()) std::abort();  // 1.5 -> 1
    const double a = written.get<double>(), b = effective.get<double>();
    if (!(std::fabs(a - b) <= resolution(key) + 1e-15 * std::fabs(a))) std::abort();
    return;
  }
  if (written != effective) std::abort();  // booleans, strings; a type changed on the way
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  unit::UnitConfig config;
  try {
    unit::parse_config_json(text, "fuzz.json", config);
    unit::validate(config);
  } catch (const unit::ConfigError& e) {
    // FUZZ_DEBUG=1: say why each input was refused (when writing seeds that must pass).
    if (std::getenv("FUZZ_DEBUG")) std::fprintf(stderr, "refused: %s\n", e.what());
    if (std::string(e.what()).empty()) std::abort();
    return 0;
  }
  check_ranges(config);
  const std::string effective = unit::to_json(config);
  check_as_written(json::parse(text), json::parse(effective), "");
  unit::UnitConfig again;
  try {
    unit::parse_config_json(effective, "print-config", again);
    unit::validate(again);
  } catch (const unit::ConfigError&) {
    std::abort();  // print-config wrote what the reader refuses
  }
  if (unit::to_json(again) != effective) std::abort();
  return 0;
}
