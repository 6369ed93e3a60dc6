#include "unit_config.hpp"

#include <cmath>
#include <fstream>
#include <initializer_list>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <type_traits>
#include <utility>
#include <vector>

#include "storetrack/health/register_map.hpp"

namespace storetrack::unit {
namespace {

using nlohmann::json;

void allow_only(const json& j, const std::string& where, std::initializer_list<const char*> keys) {
  if (!j.is_object()) throw ConfigError(where + ": expected an object");
  const std::set<std::string> allowed(keys.begin(), keys.end());
  for (const auto& [k, v] : j.items()) {
    if (!allowed.count(k)) {
      std::string list;
      for (const auto& a : allowed)
        list += (list.empty() ? "" : ", ") + a;
      throw ConfigError(where + ": unknown key '" + k + "' (allowed: " + list + ")");
    }
  }
}

template <typename T>
struct is_vector : std::false_type {};
template <typename T>
struct is_vector<std::vector<T>> : std::true_type {};

// The value as T only when it is T's kind and T holds it exactly: nlohmann's get<int>() gave
// 4294967296 as 0, 1.5 as 1 and -1 (as unsigned) as 4294967295, and a float beyond the
// integer's range was undefined behaviour.
template <typename T>
T exact(const json& v, const std::string& where) {
  if constexpr (std::is_same_v<T, bool>) {
    if (!v.is_boolean()) throw ConfigError(where + ": expected true or false, got " + v.dump());
    return v.get<bool>();
  } else if constexpr (std::is_integral_v<T>) {
    using limits = std::numeric_limits<T>;
    const bool fits = v.is_number_unsigned()
                          ? std::cmp_less_equal(v.get<std::uint64_t>(), limits::max())
                          : v.is_number_integer() &&
                                std::cmp_greater_equal(v.get<std::int64_t>(), limits::min()) &&
                                std::cmp_less_equal(v.get<std::int64_t>(), limits::max());
    if (!fits) {
      throw ConfigError(where + ": expected an integer in [" + std::to_string(limits::min()) +
                        ", " + std::to_string(limits::max()) + "], got " + v.dump());
    }
    return v.get<T>();
  } else if constexpr (std::is_floating_point_v<T>) {
    if (!v.is_number()) throw ConfigError(where + ": expected a number, got " + v.dump());
    return v.get<T>();
  } else if constexpr (is_vector<T>::value) {
    if (!v.is_array()) throw ConfigError(where + ": expected an array, got " + v.dump());
    T out;
    for (std::size_t i = 0; i < v.size(); ++i)
      out.push_back(exact<typename T::value_type>(v[i], where + "[" + std::to_string(i) + "]"));
    return out;
  } else {
    static_assert(std::is_same_v<T, std::string>);
    if (!v.is_string()) throw ConfigError(where + ": expected a string, got " + v.dump());
    return v.get<std::string>();
  }
}

template <typename T>
void get(const json& j, const char* key, T& out, const std::string& where) {
  if (j.contains(key)) out = exact<T>(j.at(key), where + "." + key);
}

// A list of objects: an array (an object's values or a number were taken as its elements).
const json& array_member(const json& j, const char* key, const std::string& where) {
  const json& a = j.at(key);
  if (!a.is_array()) throw ConfigError(where + "." + key + ": expected an array, got " + a.dump());
  return a;
}

// A duration in seconds held in whole ns (rounded: print-config writes it back in seconds).
std::int64_t seconds_to_ns(double s) {
  return std::llround(s * 1e9);
}

void parse_ptp4l(const json& x, const std::string& w, clock::ClockMonitorConfig& c) {
  allow_only(
      x, w,
      {"uds_path", "client_dir", "reply_timeout_ms", "domain_number", "lock_threshold_ns",
       "lock_polls", "holdover_s", "offset_max_age_s", "measure_only", "require_time_traceable"});
  get(x, "uds_path", c.ptp4l.uds_path, w);
  get(x, "client_dir", c.ptp4l.client_dir, w);
  get(x, "reply_timeout_ms", c.ptp4l.reply_timeout_ms, w);
  int domain = c.ptp4l.domain_number;
  get(x, "domain_number", domain, w);
  if (domain < 0 || domain > 127) throw ConfigError(w + ".domain_number must be in [0, 127]");
  c.ptp4l.domain_number = static_cast<std::uint8_t>(domain);
  get(x, "lock_threshold_ns", c.lock.lock_threshold_ns, w);
  get(x, "lock_polls", c.lock.lock_polls, w);
  if (x.contains("holdover_s")) {
    double holdover_s = 0;
    get(x, "holdover_s", holdover_s, w);
    if (!(holdover_s >= 0 && holdover_s <= 3600))
      throw ConfigError(w + ".holdover_s must be in [0, 3600]");
    c.lock.holdover_ns = seconds_to_ns(holdover_s);
  }
  if (x.contains("offset_max_age_s")) {
    double age_s = 0;
    get(x, "offset_max_age_s", age_s, w);
    if (!(age_s >= 0.1 && age_s <= 60))
      throw ConfigError(w + ".offset_max_age_s must be in [0.1, 60]");
    c.lock.offset_max_age_ns = seconds_to_ns(age_s);
  }
  get(x, "measure_only", c.lock.measure_only, w);
  get(x, "require_time_traceable", c.lock.require_time_traceable, w);
}

}  // namespace

SourceType parse_source(const std::string& s) {
  if (s == "sim") return SourceType::kSim;
  if (s == "replay") return SourceType::kReplay;
  if (s == "v4l2") return SourceType::kV4l2;
  if (s == "none") return SourceType::kNone;
  throw ConfigError("source must be sim, replay, v4l2 or none, not '" + s + "'");
}

TriggerMode parse_trigger_mode(const std::string& s) {
  if (s == "none") return TriggerMode::kNone;
  if (s == "sim") return TriggerMode::kSim;
  if (s == "gpio-master") return TriggerMode::kGpioMaster;
  if (s == "gpio-slave") return TriggerMode::kGpioSlave;
  throw ConfigError("trigger mode must be none, sim, gpio-master or gpio-slave, not '" + s + "'");
}

const char* to_string(SourceType s) {
  switch (s) {
    case SourceType::kSim:
      return "sim";
    case SourceType::kReplay:
      return "replay";
    case SourceType::kV4l2:
      return "v4l2";
    case SourceType::kNone:
      return "none";
  }
  return "?";
}

const char* to_string(TriggerMode m) {
  switch (m) {
    case TriggerMode::kNone:
      return "none";
    case TriggerMode::kSim:
      return "sim";
    case TriggerMode::kGpioMaster:
      return "gpio-master";
    case TriggerMode::kGpioSlave:
      return "gpio-slave";
  }
  return "?";
}

namespace {

void parse_camera(const json& x, const std::string& w, UnitConfig& c) {
  allow_only(x, w, {"reopen_first_ms", "reopen_max_ms", "faults"});
  get(x, "reopen_first_ms", c.camera_reopen_first_ms, w);
  get(x, "reopen_max_ms", c.camera_reopen_max_ms, w);
  if (!x.contains("faults")) return;
  const json& f = x["faults"];
  allow_only(f, w + ".faults", {"disconnect_after_frames", "failed_reopens", "corrupt_frames"});
  get(f, "disconnect_after_frames", c.camera_faults.disconnect_after_frames, w + ".faults");
  get(f, "failed_reopens", c.camera_faults.failed_reopens, w + ".faults");
  get(f, "corrupt_frames", c.camera_faults.corrupt_frames, w + ".faults");
}

}  // namespace

void parse_config_json(const std::string& text, const std::string& origin, UnitConfig& c) {
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {  // parse_error, and out_of_range for 1e400
    throw ConfigError(origin + ": " + e.what());
  }
  const std::string w = origin;
  allow_only(j, w,
             {"unit_id", "camera_id", "source", "trigger", "centroid", "roi", "links", "health",
              "modbus", "clock_state", "ptp4l", "exposure_us", "camera", "run"});
  get(j, "unit_id", c.unit_id, w);
  get(j, "camera_id", c.camera_id, w);
  get(j, "clock_state", c.clock_state, w);
  get(j, "exposure_us", c.exposure_us, w);
  if (j.contains("source")) {
    const json& s = j["source"];
    const std::string ws = w + ".source";
    allow_only(s, ws, {"type", "sim", "replay", "v4l2"});
    if (s.contains("type")) {
      std::string type;
      get(s, "type", type, ws);
      c.source = parse_source(type);
    }
    if (s.contains("sim")) {
      const json& x = s["sim"];
      allow_only(x, ws + ".sim", {"scenario", "camera_index", "seed", "realtime"});
      get(x, "scenario", c.sim.scenario, ws + ".sim");
      get(x, "camera_index", c.sim.camera_index, ws + ".sim");
      get(x, "seed", c.sim.seed, ws + ".sim");
      get(x, "realtime", c.sim.realtime, ws + ".sim");
    }
    if (s.contains("replay")) {
      const json& x = s["replay"];
      allow_only(x, ws + ".replay", {"directory", "rate_hz", "loop"});
      get(x, "directory", c.replay.directory, ws + ".replay");
      get(x, "rate_hz", c.replay.rate_hz, ws + ".replay");
      get(x, "loop", c.replay.loop, ws + ".replay");
    }
    if (s.contains("v4l2")) {
      const json& x = s["v4l2"];
      const std::string wv = ws + ".v4l2";
      allow_only(x, wv,
                 {"device", "width", "height", "allow_size_change", "buffers", "input",
                  "timestamp_to_exposure_start_ns", "controls", "exposure_control",
                  "exposure_control_unit_us"});
      auto& d = c.v4l2.device;
      get(x, "device", d.device, wv);
      get(x, "width", d.width, wv);
      get(x, "height", d.height, wv);
      get(x, "allow_size_change", d.allow_size_change, wv);
      get(x, "buffers", d.buffers, wv);
      get(x, "input", d.input, wv);
      get(x, "timestamp_to_exposure_start_ns", d.timestamp_to_exposure_start_ns, wv);
      get(x, "exposure_control", c.v4l2.exposure_control, wv);
      get(x, "exposure_control_unit_us", c.v4l2.exposure_control_unit_us, wv);
      if (x.contains("controls")) {
        d.controls.clear();
        for (const json& cj : array_member(x, "controls", wv)) {
          allow_only(cj, wv + ".controls[]", {"name", "value", "required"});
          capture::V4L2Control ctl;
          get(cj, "name", ctl.name, wv + ".controls[]");
          get(cj, "value", ctl.value, wv + ".controls[]");
          get(cj, "required", ctl.required, wv + ".controls[]");
          d.controls.push_back(ctl);
        }
      }
    }
  }
  if (j.contains("trigger")) {
    const json& t = j["trigger"];
    const std::string wt = w + ".trigger";
    allow_only(t, wt,
               {"mode", "rate_hz", "pulse_width_us", "chip", "lines", "line", "active_low",
                "latency_ns", "match_tolerance_ns", "edge_phase_tolerance_ns",
                "trigger_to_exposure_ns", "sim_jitter_ns", "sim_drop_every", "sim_extra_every",
                "sim_read_error_every", "edges_csv", "triggered_only"});
    if (t.contains("mode")) {
      std::string mode;
      get(t, "mode", mode, wt);
      c.trigger.mode = parse_trigger_mode(mode);
    }
    get(t, "rate_hz", c.trigger.rate_hz, wt);
    if (t.contains("pulse_width_us")) {
      double pulse_width_us = 0;
      get(t, "pulse_width_us", pulse_width_us, wt);
      // Held in whole ns (rounded: print-config writes it back in us); validate() checks it
      // against the period, here only that it is a number of ns at all (1e300 was UB).
      if (!(std::fabs(pulse_width_us) <= 1e12))
        throw ConfigError(wt + ".pulse_width_us must be in [-1e12, 1e12]");
      c.trigger.pulse_width_ns = std::llround(pulse_width_us * 1000);
    }
    get(t, "chip", c.trigger.chip, wt);
    get(t, "lines", c.trigger.lines, wt);
    get(t, "line", c.trigger.line, wt);
    get(t, "active_low", c.trigger.active_low, wt);
    get(t, "latency_ns", c.trigger.latency_ns, wt);
    get(t, "match_tolerance_ns", c.trigger.match_tolerance_ns, wt);
    get(t, "edge_phase_tolerance_ns", c.trigger.edge_phase_tolerance_ns, wt);
    get(t, "trigger_to_exposure_ns", c.trigger.trigger_to_exposure_ns, wt);
    get(t, "sim_jitter_ns", c.trigger.sim_jitter_ns, wt);
    get(t, "sim_drop_every", c.trigger.sim_drop_every, wt);
    get(t, "sim_extra_every", c.trigger.sim_extra_every, wt);
    get(t, "sim_read_error_every", c.trigger.sim_read_error_every, wt);
    get(t, "edges_csv", c.trigger.edges_csv, wt);
    get(t, "triggered_only", c.trigger.triggered_only, wt);
  }
  if (j.contains("centroid")) {
    const json& x = j["centroid"];
    const std::string wc = w + ".centroid";
    allow_only(x, wc,
               {"threshold_dn", "threshold_sigma", "min_area_px", "max_area_px", "read_noise_e",
                "gain_e_per_dn", "black_level_dn", "saturation_dn", "refine", "max_axis_ratio",
                "background_tile_px"});
    auto& cc = c.centroid;
    get(x, "threshold_dn", cc.threshold_dn, wc);
    get(x, "threshold_sigma", cc.threshold_sigma, wc);
    get(x, "min_area_px", cc.min_area_px, wc);
    get(x, "max_area_px", cc.max_area_px, wc);
    get(x, "read_noise_e", cc.read_noise_e, wc);
    get(x, "gain_e_per_dn", cc.gain_e_per_dn, wc);
    get(x, "black_level_dn", cc.black_level_dn, wc);
    get(x, "saturation_dn", cc.saturation_dn, wc);
    get(x, "refine", cc.refine, wc);
    get(x, "max_axis_ratio", cc.max_axis_ratio, wc);
    get(x, "background_tile_px", cc.background_tile_px, wc);
  }
  if (j.contains("roi")) {
    const json& x = j["roi"];
    allow_only(x, w + ".roi", {"x", "y", "width", "height"});
    get(x, "x", c.roi_x, w + ".roi");
    get(x, "y", c.roi_y, w + ".roi");
    get(x, "width", c.roi_width, w + ".roi");
    get(x, "height", c.roi_height, w + ".roi");
  }
  if (j.contains("links")) {
    const json& x = j["links"];
    allow_only(x, w + ".links", {"udp", "canfd"});
    if (x.contains("udp")) {
      c.udp.clear();
      for (const json& u : array_member(x, "udp", w + ".links")) {
        const std::string wu = w + ".links.udp[]";
        allow_only(u, wu,
                   {"destination", "multicast_interface", "multicast_ttl", "multicast_loop",
                    "send_buffer_bytes", "dscp"});
        link::UdpLinkConfig l;
        get(u, "destination", l.destination, wu);
        get(u, "multicast_interface", l.multicast_interface, wu);
        get(u, "multicast_ttl", l.multicast_ttl, wu);
        get(u, "multicast_loop", l.multicast_loop, wu);
        get(u, "send_buffer_bytes", l.send_buffer_bytes, wu);
        get(u, "dscp", l.dscp, wu);
        c.udp.push_back(l);
      }
    }
    if (x.contains("canfd")) {
      c.canfd.clear();
      for (const json& u : array_member(x, "canfd", w + ".links")) {
        const std::string wu = w + ".links.canfd[]";
        allow_only(u, wu, {"interface", "send_buffer_bytes", "bytes_per_queued_frame"});
        link::CanFdLinkConfig l;
        get(u, "interface", l.interface, wu);
        get(u, "send_buffer_bytes", l.send_buffer_bytes, wu);
        get(u, "bytes_per_queued_frame", l.bytes_per_queued_frame, wu);
        c.canfd.push_back(l);
      }
    }
  }
  if (j.contains("health")) {
    allow_only(j["health"], w + ".health", {"period_ms", "board_temp_root"});
    get(j["health"], "period_ms", c.health_period_ms, w + ".health");
    get(j["health"], "board_temp_root", c.board_temp_root, w + ".health");
  }
  if (j.contains("modbus")) {
    const json& x = j["modbus"];
    allow_only(x, w + ".modbus", {"enabled", "address", "port", "maintenance"});
    get(x, "enabled", c.modbus_enabled, w + ".modbus");
    get(x, "address", c.modbus_address, w + ".modbus");
    get(x, "port", c.modbus_port, w + ".modbus");
    get(x, "maintenance", c.maintenance, w + ".modbus");
  }
  if (j.contains("camera")) parse_camera(j["camera"], w + ".camera", c);
  if (j.contains("ptp4l")) parse_ptp4l(j["ptp4l"], w + ".ptp4l", c.ptp4l);
  if (j.contains("run")) {
    const json& x = j["run"];
    allow_only(x, w + ".run", {"frames", "duration_s", "stats_json", "max_consecutive_errors"});
    get(x, "frames", c.frames, w + ".run");
    get(x, "duration_s", c.duration_s, w + ".run");
    get(x, "stats_json", c.stats_json, w + ".run");
    get(x, "max_consecutive_errors", c.max_consecutive_errors, w + ".run");
  }
}

void load_config_file(const std::string& path, UnitConfig& config) {
  std::ifstream in(path);
  if (!in) throw ConfigError(path + ": cannot open configuration file");
  std::stringstream ss;
  ss << in.rdbuf();
  parse_config_json(ss.str(), path, config);
}

namespace {

void validate_ptp4l(const clock::ClockMonitorConfig& p, int health_period_ms) {
  if (const std::string problem = clock::socket_path_problem(p.ptp4l); !problem.empty())
    throw ConfigError(problem);
  if (p.lock.lock_threshold_ns < 1 || p.lock.lock_threshold_ns > 1'000'000'000)
    throw ConfigError("ptp4l.lock_threshold_ns must be in [1, 1e9]");
  if (p.lock.lock_polls < 1 || p.lock.lock_polls > 100)
    throw ConfigError("ptp4l.lock_polls must be in [1, 100]");
  // One poll is three requests; all three must fit in the health period that paces them.
  if (p.ptp4l.reply_timeout_ms < 1 || 3 * p.ptp4l.reply_timeout_ms >= health_period_ms)
    throw ConfigError("ptp4l.reply_timeout_ms must be >= 1 and 3 x it < health.period_ms");
}

}  // namespace

void validate(const UnitConfig& c) {
  auto in_range = [](const char* name, long v, long lo, long hi) {
    if (v < lo || v > hi) {
      throw ConfigError(std::string(name) + " = " + std::to_string(v) + " outside [" +
                        std::to_string(lo) + ", " + std::to_string(hi) + "]");
    }
  };
  using health::holding_def;
  using health::HoldingField;
  in_range("unit_id", c.unit_id, holding_def(HoldingField::kUnitId).min,
           holding_def(HoldingField::kUnitId).max);
  in_range("camera_id", c.camera_id, holding_def(HoldingField::kCameraId).min,
           holding_def(HoldingField::kCameraId).max);
  in_range("exposure_us", c.exposure_us, holding_def(HoldingField::kExposureUs).min,
           holding_def(HoldingField::kExposureUs).max);
  if (!(c.trigger.rate_hz > 0 && c.trigger.rate_hz <= 400)) {
    throw ConfigError("trigger.rate_hz must be in (0, 400]");
  }
  if (c.trigger.pulse_width_ns <= 0 ||
      static_cast<double>(c.trigger.pulse_width_ns) >= 0.9e9 / c.trigger.rate_hz) {
    throw ConfigError("trigger.pulse_width_us must be > 0 and < 90 % of the trigger period");
  }
  if (c.source == SourceType::kSim && c.sim.scenario.empty()) {
    throw ConfigError("source sim needs a scenario file (source.sim.scenario / --scenario)");
  }
  if (c.source == SourceType::kReplay && c.replay.directory.empty()) {
    throw ConfigError("source replay needs a directory (source.replay.directory / --replay-dir)");
  }
  if (c.source == SourceType::kNone && c.trigger.mode == TriggerMode::kNone) {
    throw ConfigError("source none (trigger-only run) needs a trigger mode");
  }
  if (c.source == SourceType::kNone && c.trigger.mode == TriggerMode::kSim) {
    throw ConfigError("source none needs a GPIO trigger (the sim trigger follows the frames)");
  }
  if (c.trigger.triggered_only &&
      (c.trigger.mode == TriggerMode::kNone || c.source == SourceType::kNone)) {
    throw ConfigError("trigger.triggered_only needs a frame source and a trigger mode");
  }
  if (c.roi_x < 0 || c.roi_y < 0 || c.roi_width < 0 || c.roi_height < 0) {
    throw ConfigError("roi values must be >= 0");
  }
  if (c.health_period_ms < 10) throw ConfigError("health.period_ms must be >= 10");
  if (c.camera_reopen_first_ms < 1 || c.camera_reopen_first_ms > 60000 ||
      c.camera_reopen_max_ms < c.camera_reopen_first_ms || c.camera_reopen_max_ms > 60000)
    throw ConfigError(
        "camera.reopen_first_ms must be in [1, 60000] and camera.reopen_max_ms in "
        "[reopen_first_ms, 60000]");
  if (c.camera_faults.failed_reopens < 0 || c.camera_faults.failed_reopens > 1000)
    throw ConfigError("camera.faults.failed_reopens must be in [0, 1000]");
  if (c.modbus_port < 0 || c.modbus_port > 65535) throw ConfigError("modbus.port out of range");
  if (c.frames < 0 || c.duration_s < 0) throw ConfigError("frames and duration_s must be >= 0");
  static const std::set<std::string> states = {"auto",   "free-running", "locking",
                                               "locked", "holdover",     "ptp4l"};
  if (!states.count(c.clock_state)) {
    throw ConfigError("clock_state must be auto, free-running, locking, locked, holdover or ptp4l");
  }
  if (c.clock_state == "ptp4l") validate_ptp4l(c.ptp4l, c.health_period_ms);
}

std::string to_json(const UnitConfig& c) {
  json j;
  j["unit_id"] = c.unit_id;
  j["camera_id"] = c.camera_id;
  j["clock_state"] = c.clock_state;
  j["exposure_us"] = c.exposure_us;
  j["source"]["type"] = to_string(c.source);
  j["source"]["sim"] = {{"scenario", c.sim.scenario},
                        {"camera_index", c.sim.camera_index},
                        {"seed", c.sim.seed},
                        {"realtime", c.sim.realtime}};
  j["source"]["replay"] = {
      {"directory", c.replay.directory}, {"rate_hz", c.replay.rate_hz}, {"loop", c.replay.loop}};
  const auto& d = c.v4l2.device;
  json controls = json::array();
  for (const auto& ctl : d.controls) {
    controls.push_back({{"name", ctl.name}, {"value", ctl.value}, {"required", ctl.required}});
  }
  j["source"]["v4l2"] = {{"device", d.device},
                         {"width", d.width},
                         {"height", d.height},
                         {"allow_size_change", d.allow_size_change},
                         {"buffers", d.buffers},
                         {"input", d.input},
                         {"timestamp_to_exposure_start_ns", d.timestamp_to_exposure_start_ns},
                         {"controls", controls},
                         {"exposure_control", c.v4l2.exposure_control},
                         {"exposure_control_unit_us", c.v4l2.exposure_control_unit_us}};
  const auto& t = c.trigger;
  j["trigger"] = {{"mode", to_string(t.mode)},
                  {"rate_hz", t.rate_hz},
                  {"pulse_width_us", static_cast<double>(t.pulse_width_ns) / 1000.0},
                  {"chip", t.chip},
                  {"lines", t.lines},
                  {"line", t.line},
                  {"active_low", t.active_low},
                  {"latency_ns", t.latency_ns},
                  {"match_tolerance_ns", t.match_tolerance_ns},
                  {"edge_phase_tolerance_ns", t.edge_phase_tolerance_ns},
                  {"trigger_to_exposure_ns", t.trigger_to_exposure_ns},
                  {"sim_jitter_ns", t.sim_jitter_ns},
                  {"sim_drop_every", t.sim_drop_every},
                  {"sim_read_error_every", t.sim_read_error_every},
                  {"sim_extra_every", t.sim_extra_every},
                  {"edges_csv", t.edges_csv},
                  {"triggered_only", t.triggered_only}};
  const auto& cc = c.centroid;
  j["centroid"] = {{"threshold_dn", cc.threshold_dn},
                   {"threshold_sigma", cc.threshold_sigma},
                   {"min_area_px", cc.min_area_px},
                   {"max_area_px", cc.max_area_px},
                   {"read_noise_e", cc.read_noise_e},
                   {"gain_e_per_dn", cc.gain_e_per_dn},
                   {"black_level_dn", cc.black_level_dn},
                   {"saturation_dn", cc.saturation_dn},
                   {"refine", cc.refine},
                   {"max_axis_ratio", cc.max_axis_ratio},
                   {"background_tile_px", cc.background_tile_px}};
  j["roi"] = {{"x", c.roi_x}, {"y", c.roi_y}, {"width", c.roi_width}, {"height", c.roi_height}};
  j["links"]["udp"] = json::array();
  for (const auto& u : c.udp) {
    j["links"]["udp"].push_back({{"destination", u.destination},
                                 {"multicast_interface", u.multicast_interface},
                                 {"multicast_ttl", u.multicast_ttl},
                                 {"multicast_loop", u.multicast_loop},
                                 {"send_buffer_bytes", u.send_buffer_bytes},
                                 {"dscp", u.dscp}});
  }
  j["links"]["canfd"] = json::array();
  for (const auto& u : c.canfd) {
    j["links"]["canfd"].push_back({{"interface", u.interface},
                                   {"send_buffer_bytes", u.send_buffer_bytes},
                                   {"bytes_per_queued_frame", u.bytes_per_queued_frame}});
  }
  j["health"] = {{"period_ms", c.health_period_ms}, {"board_temp_root", c.board_temp_root}};
  const auto& p = c.ptp4l;
  j["ptp4l"] = {{"uds_path", p.ptp4l.uds_path},
                {"client_dir", p.ptp4l.client_dir},
                {"reply_timeout_ms", p.ptp4l.reply_timeout_ms},
                {"domain_number", p.ptp4l.domain_number},
                {"lock_threshold_ns", p.lock.lock_threshold_ns},
                {"lock_polls", p.lock.lock_polls},
                {"holdover_s", static_cast<double>(p.lock.holdover_ns) / 1e9},
                {"offset_max_age_s", static_cast<double>(p.lock.offset_max_age_ns) / 1e9},
                {"measure_only", p.lock.measure_only},
                {"require_time_traceable", p.lock.require_time_traceable}};
  j["modbus"] = {{"enabled", c.modbus_enabled},
                 {"address", c.modbus_address},
                 {"port", c.modbus_port},
                 {"maintenance", c.maintenance}};
  j["camera"] = {{"reopen_first_ms", c.camera_reopen_first_ms},
                 {"reopen_max_ms", c.camera_reopen_max_ms},
                 {"faults",
                  {{"disconnect_after_frames", c.camera_faults.disconnect_after_frames},
                   {"failed_reopens", c.camera_faults.failed_reopens},
                   {"corrupt_frames", c.camera_faults.corrupt_frames}}}};
  j["run"] = {{"frames", c.frames},
              {"duration_s", c.duration_s},
              {"stats_json", c.stats_json},
              {"max_consecutive_errors", c.max_consecutive_errors}};
  return j.dump(2) + "\n";
}

}  // namespace storetrack::unit
