#include "unit_config.hpp"

#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <vector>

#include "storetrack/health/register_map.hpp"
#include "storetrack/json/strict_reader.hpp"
#include "storetrack/json/text_file.hpp"

namespace storetrack::unit {
namespace {

using jsonfile::Object;
using jsonfile::Range;
using jsonfile::Value;

// A duration in seconds held in whole ns (rounded: print-config writes it back in seconds).
std::int64_t seconds_to_ns(double s) {
  return std::llround(s * 1e9);
}

// A field whose range is the Modbus holding register's (the unit's one statement of it).
template <typename T>
void get_holding(Object& x, const char* key, T& out, health::HoldingField field) {
  const health::RegisterDef& def = health::holding_def(field);
  x.get(key, out, def.min, def.max);
}

void parse_ptp4l(Object x, clock::ClockMonitorConfig& c) {
  x.get("uds_path", c.ptp4l.uds_path);
  x.get("client_dir", c.ptp4l.client_dir);
  x.get("reply_timeout_ms", c.ptp4l.reply_timeout_ms);
  x.get("domain_number", c.ptp4l.domain_number, 0, 127);
  x.get("lock_threshold_ns", c.lock.lock_threshold_ns, 1, 1'000'000'000);
  x.get("lock_polls", c.lock.lock_polls, 1, 100);
  if (const auto v = x.find("holdover_s"))
    c.lock.holdover_ns = seconds_to_ns(v->number(Range::closed(0, 3600)));
  if (const auto v = x.find("offset_max_age_s"))
    c.lock.offset_max_age_ns = seconds_to_ns(v->number(Range::closed(0.1, 60)));
  x.get("offset_window", c.uncertainty.offset_window, 1, clock::kMaxOffsetWindow);
  if (const auto v = x.find("holdover_drift_ppb"))
    c.uncertainty.holdover_drift_ppb = v->number(Range::closed(0, 1e6));
  x.get("measure_only", c.lock.measure_only);
  x.get("require_time_traceable", c.lock.require_time_traceable);
  x.finish();
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

void parse_camera(Object x, UnitConfig& c) {
  x.get("reopen_first_ms", c.camera_reopen_first_ms);
  x.get("reopen_max_ms", c.camera_reopen_max_ms);
  if (const auto v = x.find("faults")) {
    Object f = v->object();
    f.get("disconnect_after_frames", c.camera_faults.disconnect_after_frames);
    f.get("failed_reopens", c.camera_faults.failed_reopens, 0, 1000);
    f.get("corrupt_frames", c.camera_faults.corrupt_frames);
    f.finish();
  }
  x.finish();
}

void parse_source_section(Object s, UnitConfig& c) {
  if (const auto v = s.find("type")) c.source = parse_source(v->string());
  if (const auto v = s.find("sim")) {
    Object x = v->object();
    x.get("scenario", c.sim.scenario);
    x.get("camera_index", c.sim.camera_index);
    x.get("seed", c.sim.seed);
    x.get("realtime", c.sim.realtime);
    x.finish();
  }
  if (const auto v = s.find("replay")) {
    Object x = v->object();
    x.get("directory", c.replay.directory);
    x.get("rate_hz", c.replay.rate_hz);
    x.get("loop", c.replay.loop);
    x.finish();
  }
  if (const auto v = s.find("v4l2")) {
    Object x = v->object();
    auto& d = c.v4l2.device;
    x.get("device", d.device);
    x.get("width", d.width);
    x.get("height", d.height);
    x.get("allow_size_change", d.allow_size_change);
    x.get("buffers", d.buffers);
    x.get("input", d.input);
    x.get("timestamp_to_exposure_start_ns", d.timestamp_to_exposure_start_ns);
    x.get("exposure_control", c.v4l2.exposure_control);
    x.get("exposure_control_unit_us", c.v4l2.exposure_control_unit_us);
    if (const auto controls = x.find("controls")) {
      d.controls.clear();
      for (const Value& entry : controls->array()) {
        Object cj = entry.object();
        capture::V4L2Control ctl;
        cj.get("name", ctl.name);
        cj.get("value", ctl.value);
        cj.get("required", ctl.required);
        cj.finish();
        d.controls.push_back(ctl);
      }
    }
    x.finish();
  }
  s.finish();
}

void parse_trigger(Object t, UnitConfig& c) {
  if (const auto v = t.find("mode")) c.trigger.mode = parse_trigger_mode(v->string());
  t.get("rate_hz", c.trigger.rate_hz, Range{0, 400, true});
  // Held in whole ns (rounded: print-config writes it back in us); validate() checks it against
  // the period, here only that it is a number of ns at all (1e300 was UB).
  if (const auto v = t.find("pulse_width_us"))
    c.trigger.pulse_width_ns = std::llround(v->number(Range::closed(-1e12, 1e12)) * 1000);
  t.get("chip", c.trigger.chip);
  t.get("lines", c.trigger.lines);
  t.get("line", c.trigger.line);
  t.get("active_low", c.trigger.active_low);
  t.get("latency_ns", c.trigger.latency_ns);
  t.get("match_tolerance_ns", c.trigger.match_tolerance_ns);
  t.get("edge_phase_tolerance_ns", c.trigger.edge_phase_tolerance_ns);
  t.get("trigger_to_exposure_ns", c.trigger.trigger_to_exposure_ns);
  t.get("sim_jitter_ns", c.trigger.sim_jitter_ns);
  t.get("sim_drop_every", c.trigger.sim_drop_every);
  t.get("sim_extra_every", c.trigger.sim_extra_every);
  t.get("sim_read_error_every", c.trigger.sim_read_error_every);
  t.get("edges_csv", c.trigger.edges_csv);
  t.get("triggered_only", c.trigger.triggered_only);
  t.finish();
}

void parse_centroid(Object x, UnitConfig& c) {
  auto& cc = c.centroid;
  x.get("threshold_dn", cc.threshold_dn);
  x.get("threshold_sigma", cc.threshold_sigma);
  x.get("min_area_px", cc.min_area_px);
  x.get("max_area_px", cc.max_area_px);
  x.get("read_noise_e", cc.read_noise_e);
  x.get("gain_e_per_dn", cc.gain_e_per_dn);
  x.get("black_level_dn", cc.black_level_dn);
  x.get("saturation_dn", cc.saturation_dn);
  x.get("refine", cc.refine);
  x.get("max_axis_ratio", cc.max_axis_ratio);
  x.get("background_tile_px", cc.background_tile_px);
  x.finish();
}

void parse_links(Object x, UnitConfig& c) {
  if (const auto v = x.find("udp")) {
    c.udp.clear();
    for (const Value& entry : v->array()) {
      Object u = entry.object();
      link::UdpLinkConfig l;
      u.get("destination", l.destination);
      u.get("multicast_interface", l.multicast_interface);
      u.get("multicast_ttl", l.multicast_ttl);
      u.get("multicast_loop", l.multicast_loop);
      u.get("send_buffer_bytes", l.send_buffer_bytes);
      u.get("dscp", l.dscp);
      u.finish();
      c.udp.push_back(l);
    }
  }
  if (const auto v = x.find("canfd")) {
    c.canfd.clear();
    for (const Value& entry : v->array()) {
      Object u = entry.object();
      link::CanFdLinkConfig l;
      u.get("interface", l.interface);
      u.get("send_buffer_bytes", l.send_buffer_bytes);
      u.get("bytes_per_queued_frame", l.bytes_per_queued_frame);
      u.finish();
      c.canfd.push_back(l);
    }
  }
  x.finish();
}

void parse_time(Object x, TimeUncertaintyConfig& t) {
  const Range ns = Range::closed(0, 1e9);
  if (const auto v = x.find("clock_sigma_ns"))
    t.clock_sigma_ns = v->json().is_string() && v->string() == "auto" ? -1 : v->number(ns);
  if (const auto v = x.find("latch_jitter_ns")) t.latch_jitter_ns = v->number(ns);
  if (const auto v = x.find("sensor_start_jitter_ns")) t.sensor_start_jitter_ns = v->number(ns);
  x.finish();
}

void parse_run(Object x, UnitConfig& c) {
  x.get("frames", c.frames);
  x.get("duration_s", c.duration_s);
  x.get("stats_json", c.stats_json);
  x.get("max_consecutive_errors", c.max_consecutive_errors);
  x.finish();
}

void read_config(const Value& root, UnitConfig& c) {
  Object j = root.object();
  get_holding(j, "unit_id", c.unit_id, health::HoldingField::kUnitId);
  get_holding(j, "camera_id", c.camera_id, health::HoldingField::kCameraId);
  j.get("clock_state", c.clock_state);
  get_holding(j, "exposure_us", c.exposure_us, health::HoldingField::kExposureUs);
  if (const auto v = j.find("source")) parse_source_section(v->object(), c);
  if (const auto v = j.find("trigger")) parse_trigger(v->object(), c);
  if (const auto v = j.find("centroid")) parse_centroid(v->object(), c);
  if (const auto v = j.find("roi")) {
    Object x = v->object();
    x.get("x", c.roi_x, 0, std::numeric_limits<int>::max());
    x.get("y", c.roi_y, 0, std::numeric_limits<int>::max());
    x.get("width", c.roi_width, 0, std::numeric_limits<int>::max());
    x.get("height", c.roi_height, 0, std::numeric_limits<int>::max());
    x.finish();
  }
  if (const auto v = j.find("links")) parse_links(v->object(), c);
  if (const auto v = j.find("health")) {
    Object x = v->object();
    x.get("period_ms", c.health_period_ms, 10, std::numeric_limits<int>::max());
    x.get("board_temp_root", c.board_temp_root);
    x.finish();
  }
  if (const auto v = j.find("modbus")) {
    Object x = v->object();
    x.get("enabled", c.modbus_enabled);
    x.get("address", c.modbus_address);
    x.get("port", c.modbus_port, 0, 65535);
    x.get("maintenance", c.maintenance);
    x.finish();
  }
  if (const auto v = j.find("camera")) parse_camera(v->object(), c);
  if (const auto v = j.find("ptp4l")) parse_ptp4l(v->object(), c.ptp4l);
  if (const auto v = j.find("time")) parse_time(v->object(), c.time);
  if (const auto v = j.find("run")) parse_run(v->object(), c);
  j.finish();
}

}  // namespace

void parse_config_json(const std::string& text, const std::string& origin, UnitConfig& c) {
  try {
    const jsonfile::Document doc = jsonfile::Document::parse(text, origin);
    read_config(doc.root(), c);
  } catch (const jsonfile::FieldError& e) {
    throw ConfigError(e.what());
  }
}

void load_config_file(const std::string& path, UnitConfig& config) {
  std::string text;
  try {
    text = jsonfile::read_text_file(path);
  } catch (const jsonfile::FileReadError& e) {
    throw ConfigError(std::string(e.what()) + " (configuration file)");
  }
  parse_config_json(text, path, config);
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
  using nlohmann::json;
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
                {"offset_window", p.uncertainty.offset_window},
                {"holdover_drift_ppb", p.uncertainty.holdover_drift_ppb},
                {"measure_only", p.lock.measure_only},
                {"require_time_traceable", p.lock.require_time_traceable}};
  j["time"] = {{"latch_jitter_ns", c.time.latch_jitter_ns},
               {"sensor_start_jitter_ns", c.time.sensor_start_jitter_ns}};
  if (c.time.clock_sigma_ns < 0)
    j["time"]["clock_sigma_ns"] = "auto";
  else
    j["time"]["clock_sigma_ns"] = c.time.clock_sigma_ns;
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
