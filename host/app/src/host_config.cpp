#include "host_config.hpp"

#include <arpa/inet.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <sstream>

#include "storetrack/json/strict_reader.hpp"

namespace storetrack::hostapp {
namespace {

using jsonfile::Object;
using jsonfile::Range;
using jsonfile::Value;

std::string range_text(double lo, bool lo_open, double hi) {
  return Range{lo, hi, lo_open, false}.text();
}

// The reader's refusals (file, field path, reason) as the host's error type.
template <typename Read>
auto as_host_config_error(Read&& read) {
  try {
    return read();
  } catch (const jsonfile::FieldError& e) {
    throw HostConfigError(e.what());
  }
}

// Mark ids of surveys and initial marks: small non-negative integers; the bound only keeps a
// typo (or 1e300) from becoming an id.
constexpr std::int64_t kMaxMarkIds = 1'000'000;

std::int64_t ms_to_ns(double ms) {
  return static_cast<std::int64_t>(std::llround(ms * 1e6));
}

void check_address(const std::string& address, const std::string& what) {
  in_addr a{};
  if (inet_pton(AF_INET, address.c_str(), &a) != 1)
    throw HostConfigError(what + " must be an IPv4 address a.b.c.d (got '" + address + "')");
}

std::string id_list(const std::vector<int>& ids) {
  std::string out;
  for (int id : ids)
    out += (out.empty() ? "" : ", ") + std::to_string(id);
  return out;
}

}  // namespace

void set_max_wait_ms(HostConfig& c, double max_wait_ms, const std::string& where) {
  const double max_ms = static_cast<double>(ingest::kMaxAlignerWaitNs) * 1e-6;
  if (!std::isfinite(max_wait_ms) || !(max_wait_ms > 0) || !(max_wait_ms <= max_ms))
    throw HostConfigError(where + " must be a number in " + range_text(0, true, max_ms) +
                          " ms (got " + jsonfile::number_text(max_wait_ms) + ")");
  c.aligner.max_wait_ns = ms_to_ns(max_wait_ms);
}

UdpSource parse_udp_source(const std::string& text) {
  const auto at = text.find('@');
  UdpSource s;
  try {
    std::size_t used = 0;
    if (at == std::string::npos || at == 0) throw std::invalid_argument("no unit");
    s.unit_id = std::stoi(text.substr(0, at), &used);
    if (used != at) throw std::invalid_argument("not a number");
  } catch (const std::exception&) {
    throw HostConfigError("--udp-source must be UNIT@a.b.c.d (got '" + text + "')");
  }
  s.address = text.substr(at + 1);
  return s;
}

void finish_host_config(HostConfig& c, const std::vector<int>& camera_ids,
                        const std::vector<int>& unit_ids) {
  c.aligner.camera_ids = camera_ids;
  c.aligner.unit_ids = unit_ids;
  if (c.aligner.min_cameras < 1 ||
      static_cast<std::size_t>(c.aligner.min_cameras) > camera_ids.size())
    throw HostConfigError("aligner.min_cameras (--min-cameras) must be in [1, " +
                          std::to_string(camera_ids.size()) + "] (the rig's cameras; got " +
                          std::to_string(c.aligner.min_cameras) + ")");
  if (c.udp_port < 0 || c.udp_port > 65535)
    throw HostConfigError("udp.port must be an integer in [0, 65535] (0: no UDP; got " +
                          std::to_string(c.udp_port) + ")");
  if (c.udp_port > 0) {
    if (c.udp_bind.empty())
      throw HostConfigError(
          "udp.bind (--udp-bind) is required with UDP: the address of the FTI network "
          "interface to receive on (0.0.0.0 receives on every interface; say so explicitly)");
    check_address(c.udp_bind, "udp.bind (--udp-bind)");
  }
  for (const auto& s : c.udp_sources) {
    if (s.unit_id < 0 || s.unit_id > 254)
      throw HostConfigError("udp.sources.unit_id (--udp-source) must be in [0, 254] (got " +
                            std::to_string(s.unit_id) + ")");
    check_address(s.address, "udp.sources.address (--udp-source)");
  }
  for (int id : c.calibration_health.camera_ids)
    if (std::find(camera_ids.begin(), camera_ids.end(), id) == camera_ids.end())
      throw HostConfigError("calibration_health.cameras: camera " + std::to_string(id) +
                            " is not in the rig (its cameras: " + id_list(camera_ids) + ")");
}

namespace {

// One function per section of the configuration file; each reads only its own object and
// refuses the keys it does not know.

void parse_udp_sources(const Value& sources, HostConfig& c) {
  // [{"unit_id": 0, "address": "10.0.0.10"}, ...]: the only senders accepted.
  c.udp_sources.clear();
  for (const Value& entry : sources.array()) {
    Object s = entry.object();
    UdpSource src;
    src.unit_id = static_cast<int>(s.at("unit_id").integer(0, 254));
    const Value address = s.at("address");
    src.address = address.string();
    s.finish();
    in_addr a{};
    if (inet_pton(AF_INET, src.address.c_str(), &a) != 1)
      address.fail("expected an IPv4 address a.b.c.d, got '" + src.address + "'");
    c.udp_sources.push_back(src);
  }
}

void parse_udp(Object u, HostConfig& c) {
  u.get("bind", c.udp_bind);
  u.get("port", c.udp_port, 0, 65535);
  u.get("group", c.udp_group);
  u.get("interface", c.udp_interface);
  u.get("kernel_filter", c.udp_kernel_filter);
  if (const auto sources = u.find("sources")) parse_udp_sources(*sources, c);
  u.finish();
}

void parse_aligner(Object a, ingest::AlignerConfig& al) {
  const double max_wait_ms = static_cast<double>(ingest::kMaxAlignerWaitNs) * 1e-6;
  if (const auto v = a.find("max_wait_ms"))
    al.max_wait_ns = ms_to_ns(v->number(Range{0, max_wait_ms, true}));
  const double max_spread_ms = static_cast<double>(ingest::kMaxMidTimeSpreadNs) * 1e-6;
  if (const auto v = a.find("max_mid_time_spread_ms"))
    al.max_mid_time_spread_ns = ms_to_ns(v->number(Range::closed(0, max_spread_ms)));
  a.get("max_pending", al.max_pending, 1, static_cast<std::int64_t>(ingest::kMaxAlignerPending));
  a.get("min_cameras", al.min_cameras, 1, static_cast<std::int64_t>(ingest::kMaxAlignerCameras));
  a.get("max_sequence_lead", al.max_sequence_lead, 1, ingest::kMaxSequenceLead);
  a.finish();
}

void parse_processor(Object p, HostConfig& c) {
  auto& pc = c.processor;
  p.get("store_id", pc.store_id, 0, 254);
  p.get("coverage_factor", pc.coverage_factor, Range::above(0));
  p.get("min_cameras_per_mark", pc.min_cameras_per_mark, 1,
        static_cast<std::int64_t>(ingest::kMaxAlignerCameras));
  p.get("min_pose_marks", pc.min_pose_marks, 3, 1024);
  // The reference time is the matcher's (it triangulates at it): processor section, its rule.
  p.get("reference_camera_id", pc.matcher.reference_camera_id, -1, 254);
  p.get("rigid_false_alarm_probability", pc.rigid_false_alarm_probability, Range{0, 1, true, true});
  p.get("max_pose_rotation_sigma_rad", pc.max_pose_rotation_sigma_rad, Range::above(0));
  p.finish();
}

geometry::Vec3 vec3(const Value& v) {
  const std::vector<double> x = v.numbers(3);
  return {x[0], x[1], x[2]};
}

// Extrapolation of T_p_s over short gaps (host/pipeline PoseTracker, docs/uncertainty.md).
void parse_pose_tracker(Object t, HostConfig& c) {
  auto& pt = c.processor.pose_tracker;
  t.get("max_gap_s", pt.max_gap_s, Range::at_least(0));  // 0: never extrapolate
  t.get("max_velocity_baseline_s", pt.max_velocity_baseline_s, Range::above(0));
  t.get("accel_sigma_m_s2", pt.accel_sigma_m_s2, Range::above(0));
  t.get("angular_accel_sigma_rad_s2", pt.angular_accel_sigma_rad_s2, Range::above(0));
  if (const auto v = t.find("mean_accel_p_m_s2")) pt.mean_accel_p_m_s2 = vec3(*v);  // [x, y, z]
  t.get("ejector_accel_max_m_s2", pt.ejector_accel_max_m_s2, Range::at_least(0));
  t.get("ejector_angular_accel_max_rad_s2", pt.ejector_angular_accel_max_rad_s2,
        Range::at_least(0));
  t.get("ejector_duration_max_s", pt.ejector_duration_max_s, Range::at_least(0));
  t.finish();
}

// Where the store can be relative to the pylon: {max_rotation_deg, min_offset_m [x, y, z],
// max_offset_m [x, y, z]} (pylon frame, from the installation pose).
void parse_store_region(Object r, HostConfig& c) {
  auto& region = c.store_region;
  double max_rotation_deg = 45.0;
  r.get("max_rotation_deg", max_rotation_deg, Range{0, 180, true});
  region.max_rotation_rad = max_rotation_deg * std::numbers::pi / 180.0;
  region.min_offset_m = vec3(r.at("min_offset_m"));
  region.max_offset_m = vec3(r.at("max_offset_m"));
  r.finish();
  if (!(region.min_offset_m.array() <= region.max_offset_m.array()).all())
    r.fail("min_offset_m must be <= max_offset_m on every axis");
  region.valid = true;
}

// Mark identification (host/match MarkMatcher, docs/matching.md).
void parse_identifier(Object i, HostConfig& c) {
  for (const char* removed : {"gate_px", "ambiguity_ratio", "max_track_age_s"})
    if (const auto v = i.find(removed))
      v->fail(
          "no longer exists (the MarkMatcher gates by chi-square: gate_probability, "
          "track_max_gap_s, body_track_max_gap_s)");
  auto& m = c.processor.matcher;
  i.get("gate_probability", m.gate_probability, Range{0, 1, true, true});
  i.get("max_acceleration_mps2", m.max_acceleration_mps2);
  i.get("max_angular_acceleration_radps2", m.max_angular_acceleration_radps2);
  i.get("max_speed_mps", m.max_speed_mps);
  i.get("max_angular_speed_radps", m.max_angular_speed_radps);
  i.get("track_max_gap_s", m.track_max_gap_s);
  i.get("body_track_max_gap_s", m.body_track_max_gap_s);
  i.get("keep_single_view", m.keep_single_view);
  i.get("use_calibration_covariance", m.use_calibration_covariance);
  i.get("initial_marks_sigma_m", c.initial_marks_sigma_m, Range::above(0));
  i.get("reacquisition_retry_s", m.reacquisition_retry_s, Range::closed(0, 10));
  i.get("min_reacquisition_marks", m.min_reacquisition_marks, 3, 64);
  if (const auto r = i.find("store_region")) parse_store_region(r->object(), c);
  i.finish();
}

// The calibration health test (host/pipeline CalibrationHealthMonitor) and its mode.
void parse_calibration_health(Object h, HostConfig& c) {
  auto& hc = c.calibration_health;
  h.get("enabled", c.calibration_health_enabled);
  if (const auto v = h.find("mode")) {
    const std::string mode = v->string();
    if (mode == "flag")
      c.calibration_health_mode = pipeline::CalibrationHealthMode::kFlag;
    else if (mode == "correct")
      c.calibration_health_mode = pipeline::CalibrationHealthMode::kCorrect;
    else if (mode == "exclude")
      c.calibration_health_mode = pipeline::CalibrationHealthMode::kExclude;
    else
      v->fail("must be one of flag, correct, exclude (got '" + mode + "')");
  }
  h.get("window_exposures", hc.window_exposures, 2, 100000);
  h.get("baseline_windows", hc.baseline_windows, 1, 100000);
  h.get("false_alarm_probability", hc.false_alarm_probability, Range{0, 0.5, true, true});
  h.get("min_pylon_marks", hc.min_pylon_marks, 3, 1024);
  if (const auto v = h.find("cameras")) {
    hc.camera_ids.clear();
    for (const Value& id : v->array())
      hc.camera_ids.push_back(static_cast<int>(id.integer(0, 254)));
  }
  h.finish();
}

// The clearance geometry and its alarm threshold: both, or neither.
void parse_clearance(Object o, HostConfig& c) {
  o.get("geometry", c.clearance_geometry);
  o.get("alarm_threshold_m", c.clearance_alarm_threshold_m, Range::closed(-100, 100));
  o.finish();
  if (c.clearance_geometry.empty() != std::isnan(c.clearance_alarm_threshold_m))
    o.fail("needs both geometry (a clearance geometry file) and alarm_threshold_m (metres)");
}

void parse_chapter10(Object o, HostConfig& c) {
  o.get("max_messages_per_packet", c.ch10.max_messages_per_packet, 1, 65535);
  o.get("data_checksum", c.ch10.data_checksum);
  o.get("test_point", c.ch10.test_point);
  o.finish();
}

void parse_recording(Object r, HostConfig& c) {
  r.get("queue_items", c.recording_queue_items, 1, 4096);
  r.get("raw_observations", c.record_raw_observations);
  r.finish();
}

// The live page's store envelope (docs/live-view.md, coverage overlay): poses T_p_s.
void parse_live(Object l, HostConfig& c) {
  c.live_store_envelope_p.clear();
  if (const auto e = l.find("store_envelope")) {
    for (const Value& entry : e->array(1, 256)) {
      Object pose = entry.object();
      geometry::Transform T_p_s = geometry::Transform::Identity();
      T_p_s.translation() = vec3(pose.at("t_m"));
      T_p_s.linear() = geometry::rotation_from_rotvec(vec3(pose.at("rotvec_rad")));
      pose.finish();
      c.live_store_envelope_p.push_back(T_p_s);
    }
  }
  l.finish();
}

void read_host_config(const Value& root, HostConfig& c) {
  Object top = root.object();
  if (const auto v = top.find("udp")) parse_udp(v->object(), c);
  top.get("can_interfaces", c.can_interfaces);
  if (const auto v = top.find("aligner")) parse_aligner(v->object(), c.aligner);
  if (const auto v = top.find("processor")) parse_processor(v->object(), c);
  if (const auto v = top.find("pose_tracker")) parse_pose_tracker(v->object(), c);
  if (const auto v = top.find("identifier")) parse_identifier(v->object(), c);
  if (const auto v = top.find("calibration_health")) parse_calibration_health(v->object(), c);
  if (const auto v = top.find("clearance")) parse_clearance(v->object(), c);
  if (const auto v = top.find("chapter10")) parse_chapter10(v->object(), c);
  if (const auto v = top.find("recording")) parse_recording(v->object(), c);
  if (const auto v = top.find("live")) parse_live(v->object(), c);
  top.finish();
}

std::map<int, geometry::Vec3> read_initial_marks(const Value& root) {
  Object top = root.object();
  std::map<int, geometry::Vec3> out;
  for (const Value& entry : top.at("marks").array()) {
    Object m = entry.object();
    const int id = static_cast<int>(m.at("id").integer(0, kMaxMarkIds));
    const geometry::Vec3 p = vec3(m.at("p_w_m"));
    m.finish();
    if (!out.emplace(id, p).second) entry.fail("duplicate mark id " + std::to_string(id));
  }
  top.finish();
  return out;
}

}  // namespace

void load_host_config(const std::string& path, HostConfig& config) {
  as_host_config_error([&] {
    const jsonfile::Document doc = jsonfile::Document::read(path);
    read_host_config(doc.root(), config);
  });
}

void parse_host_config(const std::string& json_text, const std::string& path, HostConfig& c) {
  as_host_config_error([&] {
    const jsonfile::Document doc = jsonfile::Document::parse(json_text, path);
    read_host_config(doc.root(), c);
  });
}

std::map<int, geometry::Vec3> load_initial_marks(const std::string& path) {
  return as_host_config_error([&] {
    const jsonfile::Document doc = jsonfile::Document::read(path);
    return read_initial_marks(doc.root());
  });
}

std::map<int, geometry::Vec3> parse_initial_marks(const std::string& json_text,
                                                  const std::string& path) {
  return as_host_config_error([&] {
    const jsonfile::Document doc = jsonfile::Document::parse(json_text, path);
    return read_initial_marks(doc.root());
  });
}

}  // namespace storetrack::hostapp
