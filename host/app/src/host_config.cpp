#include "host_config.hpp"

#include <arpa/inet.h>

#include <cmath>
#include <fstream>
#include <limits>
#include <numbers>
#include <sstream>

#include <nlohmann/json.hpp>

namespace storetrack::hostapp {
namespace {

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw HostConfigError("cannot open '" + path + "'");
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

nlohmann::json parse_json(const std::string& json_text, const std::string& origin) {
  try {
    return nlohmann::json::parse(json_text);
  } catch (const nlohmann::json::exception& e) {
    throw HostConfigError(origin + ": not valid JSON: " + e.what());
  }
}

template <typename T>
void get(const nlohmann::json& j, const char* key, T& out, const std::string& where) {
  if (!j.contains(key)) return;
  try {
    out = j.at(key).get<T>();
  } catch (const nlohmann::json::exception& e) {
    throw HostConfigError(where + "/" + key + ": " + e.what());
  }
}

std::string number_text(double x) {
  std::ostringstream o;
  o << x;  // 1e+300, not 300 digits
  return o.str();
}

std::string range_text(double lo, bool lo_open, double hi) {
  std::ostringstream o;
  o << (lo_open ? "(" : "[") << lo << ", " << hi << "]";
  return o.str();
}

// A finite number in [lo, hi] (or (lo, hi]); NaN, infinities and out-of-range values refused.
double get_number(const nlohmann::json& j, const char* key, double value, double lo, bool lo_open,
                  double hi, const std::string& where) {
  if (j.contains(key) && !j.at(key).is_number())
    throw HostConfigError(where + "/" + key + " must be a number in " +
                          range_text(lo, lo_open, hi) + " (got " + j.at(key).dump() + ")");
  get(j, key, value, where);
  const bool above = lo_open ? value > lo : value >= lo;
  if (!std::isfinite(value) || !above || !(value <= hi))
    throw HostConfigError(where + "/" + key + " must be a number in " +
                          range_text(lo, lo_open, hi) + " (got " + number_text(value) + ")");
  return value;
}

// An integer in [lo, hi]: a JSON float, bool or string is refused, and so is a value that would
// wrap when cast (nlohmann converts 4294967297 to an int silently).
std::int64_t get_integer(const nlohmann::json& j, const char* key, std::int64_t value,
                         std::int64_t lo, std::int64_t hi, const std::string& where) {
  if (!j.contains(key)) return value;
  const auto& v = j.at(key);
  const std::string range =
      " must be an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
  if (!v.is_number_integer()) throw HostConfigError(where + "/" + key + range);
  if (v.is_number_unsigned() && v.get<std::uint64_t>() > static_cast<std::uint64_t>(hi))
    throw HostConfigError(where + "/" + key + range + " (got " + v.dump() + ")");
  const auto x = v.get<std::int64_t>();
  if (x < lo || x > hi)
    throw HostConfigError(where + "/" + key + range + " (got " + v.dump() + ")");
  return x;
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

}  // namespace

void set_max_wait_ms(HostConfig& c, double max_wait_ms, const std::string& where) {
  const double max_ms = static_cast<double>(ingest::kMaxAlignerWaitNs) * 1e-6;
  if (!std::isfinite(max_wait_ms) || !(max_wait_ms > 0) || !(max_wait_ms <= max_ms))
    throw HostConfigError(where + " must be a number in " + range_text(0, true, max_ms) +
                          " ms (got " + number_text(max_wait_ms) + ")");
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
    throw HostConfigError("aligner/min_cameras (--min-cameras) must be in [1, " +
                          std::to_string(camera_ids.size()) + "] (the rig's cameras; got " +
                          std::to_string(c.aligner.min_cameras) + ")");
  if (c.udp_port < 0 || c.udp_port > 65535)
    throw HostConfigError("udp/port must be an integer in [0, 65535] (0: no UDP; got " +
                          std::to_string(c.udp_port) + ")");
  if (c.udp_port > 0) {
    if (c.udp_bind.empty())
      throw HostConfigError(
          "udp/bind (--udp-bind) is required with UDP: the address of the FTI network "
          "interface to receive on (0.0.0.0 receives on every interface; say so explicitly)");
    check_address(c.udp_bind, "udp/bind (--udp-bind)");
  }
  for (const auto& s : c.udp_sources) {
    if (s.unit_id < 0 || s.unit_id > 254)
      throw HostConfigError("udp/sources/unit_id (--udp-source) must be in [0, 254] (got " +
                            std::to_string(s.unit_id) + ")");
    check_address(s.address, "udp/sources/address (--udp-source)");
  }
}

void load_host_config(const std::string& path, HostConfig& config) {
  parse_host_config(read_text(path), path, config);
}

namespace {

// One function per section of the configuration file; each reads only its own object.

void parse_udp_sources(const nlohmann::json& sources, const std::string& w, HostConfig& c) {
  // [{"unit_id": 0, "address": "10.0.0.10"}, ...]: the only senders accepted.
  if (!sources.is_array()) throw HostConfigError(w + "/sources must be an array");
  c.udp_sources.clear();
  for (const auto& s : sources) {
    if (!s.is_object()) throw HostConfigError(w + "/sources: entries must be objects");
    UdpSource src;
    src.unit_id = static_cast<int>(get_integer(s, "unit_id", -1, 0, 254, w + "/sources"));
    get(s, "address", src.address, w + "/sources");
    if (src.unit_id < 0 || src.address.empty())
      throw HostConfigError(w + "/sources: every entry needs unit_id and address");
    check_address(src.address, w + "/sources/address");
    c.udp_sources.push_back(src);
  }
}

void parse_udp(const nlohmann::json& u, const std::string& w, HostConfig& c) {
  get(u, "bind", c.udp_bind, w);
  c.udp_port = static_cast<int>(get_integer(u, "port", c.udp_port, 0, 65535, w));
  get(u, "group", c.udp_group, w);
  get(u, "interface", c.udp_interface, w);
  get(u, "kernel_filter", c.udp_kernel_filter, w);
  if (u.contains("sources")) parse_udp_sources(u["sources"], w, c);
}

void parse_aligner(const nlohmann::json& a, const std::string& w, ingest::AlignerConfig& al) {
  const double wait_ms = get_number(a, "max_wait_ms", static_cast<double>(al.max_wait_ns) * 1e-6, 0,
                                    true, static_cast<double>(ingest::kMaxAlignerWaitNs) * 1e-6, w);
  al.max_wait_ns = ms_to_ns(wait_ms);
  const double spread_ms =
      get_number(a, "max_mid_time_spread_ms", static_cast<double>(al.max_mid_time_spread_ns) * 1e-6,
                 0, false, static_cast<double>(ingest::kMaxMidTimeSpreadNs) * 1e-6, w);
  al.max_mid_time_spread_ns = ms_to_ns(spread_ms);
  al.max_pending = static_cast<std::size_t>(
      get_integer(a, "max_pending", static_cast<std::int64_t>(al.max_pending), 1,
                  static_cast<std::int64_t>(ingest::kMaxAlignerPending), w));
  al.min_cameras =
      static_cast<int>(get_integer(a, "min_cameras", al.min_cameras, 1,
                                   static_cast<std::int64_t>(ingest::kMaxAlignerCameras), w));
  al.max_sequence_lead = static_cast<std::uint32_t>(
      get_integer(a, "max_sequence_lead", al.max_sequence_lead, 1, ingest::kMaxSequenceLead, w));
}

void parse_processor(const nlohmann::json& p, const std::string& w, HostConfig& c) {
  auto& pc = c.processor;
  pc.store_id = static_cast<std::uint8_t>(get_integer(p, "store_id", pc.store_id, 0, 254, w));
  get(p, "coverage_factor", pc.coverage_factor, w);
  // Integers through get_integer: nlohmann's get<int> of 1e300 is an out-of-range cast (UB).
  pc.min_cameras_per_mark =
      static_cast<int>(get_integer(p, "min_cameras_per_mark", pc.min_cameras_per_mark, 1,
                                   static_cast<std::int64_t>(ingest::kMaxAlignerCameras), w));
  pc.min_pose_marks =
      static_cast<int>(get_integer(p, "min_pose_marks", pc.min_pose_marks, 3, 1024, w));
  pc.reference_camera_id =
      static_cast<int>(get_integer(p, "reference_camera_id", pc.reference_camera_id, -1, 254, w));
  get(p, "rigid_false_alarm_probability", pc.rigid_false_alarm_probability, w);
  get(p, "max_pose_rotation_sigma_rad", pc.max_pose_rotation_sigma_rad, w);
  if (!(pc.max_pose_rotation_sigma_rad > 0))
    throw HostConfigError(w + "/max_pose_rotation_sigma_rad must be > 0");
}

// Extrapolation of T_p_s over short gaps (host/pipeline PoseTracker, docs/uncertainty.md).
void parse_pose_tracker(const nlohmann::json& t, const std::string& w, HostConfig& c) {
  auto& pt = c.pose_tracker;
  get(t, "max_gap_s", pt.max_gap_s, w);
  get(t, "max_velocity_baseline_s", pt.max_velocity_baseline_s, w);
  get(t, "accel_sigma_m_s2", pt.accel_sigma_m_s2, w);
  get(t, "angular_accel_sigma_rad_s2", pt.angular_accel_sigma_rad_s2, w);
  if (t.contains("mean_accel_p_m_s2")) {
    std::vector<double> v;
    get(t, "mean_accel_p_m_s2", v, w);
    if (v.size() != 3 || !std::isfinite(v[0]) || !std::isfinite(v[1]) || !std::isfinite(v[2]))
      throw HostConfigError(w + "/mean_accel_p_m_s2 needs 3 finite values [x, y, z] m/s^2");
    pt.mean_accel_p_m_s2 = geometry::Vec3(v[0], v[1], v[2]);
  }
  if (!(pt.max_gap_s >= 0) || !(pt.max_velocity_baseline_s > 0) || !(pt.accel_sigma_m_s2 > 0) ||
      !(pt.angular_accel_sigma_rad_s2 > 0))
    throw HostConfigError(w + ": max_gap_s must be >= 0 (0: never extrapolate), the others > 0");
}

// Where the store can be relative to the pylon: {max_rotation_deg, min_offset_m [x, y, z],
// max_offset_m [x, y, z]} (pylon frame, from the installation pose).
void parse_store_region(const nlohmann::json& r, const std::string& w, HostConfig& c) {
  if (!r.is_object()) throw HostConfigError(w + " must be an object");
  auto& region = c.store_region;
  region.max_rotation_rad =
      get_number(r, "max_rotation_deg", 45.0, 0.0, true, 180.0, w) * std::numbers::pi / 180.0;
  for (const auto& [key, out] : {std::pair{"min_offset_m", &region.min_offset_m},
                                 std::pair{"max_offset_m", &region.max_offset_m}}) {
    if (!r.contains(key)) throw HostConfigError(w + "/" + key + " is required ([x, y, z] m)");
    std::vector<double> v;
    get(r, key, v, w);
    if (v.size() != 3 || !std::isfinite(v[0]) || !std::isfinite(v[1]) || !std::isfinite(v[2]))
      throw HostConfigError(w + "/" + key + " needs 3 finite values [x, y, z] m");
    *out = geometry::Vec3(v[0], v[1], v[2]);
  }
  if (!(region.min_offset_m.array() <= region.max_offset_m.array()).all())
    throw HostConfigError(w + ": min_offset_m must be <= max_offset_m on every axis");
  region.valid = true;
}

// Mark identification (host/match MarkMatcher, docs/matching.md).
void parse_identifier(const nlohmann::json& i, const std::string& w, HostConfig& c) {
  for (const char* removed : {"gate_px", "ambiguity_ratio", "max_track_age_s"})
    if (i.contains(removed))
      throw HostConfigError(w + "/" + removed +
                            ": no longer exists (the MarkMatcher gates by chi-square: "
                            "gate_probability, track_max_gap_s, body_track_max_gap_s)");
  auto& m = c.processor.matcher;
  get(i, "gate_probability", m.gate_probability, w);
  if (!(m.gate_probability > 0 && m.gate_probability < 1))
    throw HostConfigError(w + "/gate_probability must be in (0, 1)");
  get(i, "max_acceleration_mps2", m.max_acceleration_mps2, w);
  get(i, "max_angular_acceleration_radps2", m.max_angular_acceleration_radps2, w);
  get(i, "max_speed_mps", m.max_speed_mps, w);
  get(i, "max_angular_speed_radps", m.max_angular_speed_radps, w);
  get(i, "track_max_gap_s", m.track_max_gap_s, w);
  get(i, "body_track_max_gap_s", m.body_track_max_gap_s, w);
  get(i, "keep_single_view", m.keep_single_view, w);
  get(i, "use_calibration_covariance", m.use_calibration_covariance, w);
  get(i, "initial_marks_sigma_m", c.initial_marks_sigma_m, w);
  if (!(c.initial_marks_sigma_m > 0))
    throw HostConfigError(w + "/initial_marks_sigma_m must be > 0");
  m.reacquisition_retry_s =
      get_number(i, "reacquisition_retry_s", m.reacquisition_retry_s, 0.0, false, 10.0, w);
  m.min_reacquisition_marks = static_cast<int>(
      get_integer(i, "min_reacquisition_marks", m.min_reacquisition_marks, 3, 64, w));
  if (i.contains("store_region")) parse_store_region(i.at("store_region"), w + "/store_region", c);
}

void parse_chapter10(const nlohmann::json& o, const std::string& w, HostConfig& c) {
  c.ch10.max_messages_per_packet = static_cast<int>(
      get_integer(o, "max_messages_per_packet", c.ch10.max_messages_per_packet, 1, 65535, w));
  get(o, "data_checksum", c.ch10.data_checksum, w);
  get(o, "test_point", c.ch10.test_point, w);
}

void parse_recording(const nlohmann::json& r, const std::string& w, HostConfig& c) {
  c.recording_queue_items = static_cast<std::size_t>(get_integer(
      r, "queue_items", static_cast<std::int64_t>(c.recording_queue_items), 1, 4096, w));
}

}  // namespace

void parse_host_config(const std::string& json_text, const std::string& path, HostConfig& c) {
  const nlohmann::json j = parse_json(json_text, path);
  if (!j.is_object()) throw HostConfigError(path + ": top level must be an object");
  const std::string at = path + ": /";
  if (j.contains("udp")) parse_udp(j["udp"], at + "udp", c);
  get(j, "can_interfaces", c.can_interfaces, path + ": ");
  if (j.contains("aligner")) parse_aligner(j["aligner"], at + "aligner", c.aligner);
  if (j.contains("processor")) parse_processor(j["processor"], at + "processor", c);
  if (j.contains("pose_tracker")) parse_pose_tracker(j["pose_tracker"], at + "pose_tracker", c);
  if (j.contains("identifier")) parse_identifier(j["identifier"], at + "identifier", c);
  if (j.contains("chapter10")) parse_chapter10(j["chapter10"], at + "chapter10", c);
  if (j.contains("recording")) parse_recording(j["recording"], at + "recording", c);
}

std::map<int, geometry::Vec3> load_initial_marks(const std::string& path) {
  return parse_initial_marks(read_text(path), path);
}

std::map<int, geometry::Vec3> parse_initial_marks(const std::string& json_text,
                                                  const std::string& path) {
  const nlohmann::json j = parse_json(json_text, path);
  std::map<int, geometry::Vec3> out;
  try {
    const auto& marks = j.at("marks");
    if (!marks.is_array()) throw HostConfigError(path + ": /marks must be an array");
    for (const auto& m : marks) {
      if (!m.is_object()) throw HostConfigError(path + ": /marks: entries must be objects");
      if (!m.contains("id")) throw HostConfigError(path + ": /marks: every entry needs an id");
      const int id = static_cast<int>(get_integer(m, "id", 0, 0, kMaxMarkIds, path + ": /marks"));
      const auto p = m.at("p_w_m").get<std::vector<double>>();
      if (p.size() != 3) throw HostConfigError(path + ": /marks/p_w_m needs 3 values");
      if (!out.emplace(id, geometry::Vec3(p[0], p[1], p[2])).second)
        throw HostConfigError(path + ": /marks/id: duplicate mark id " + std::to_string(id));
    }
  } catch (const nlohmann::json::exception& e) {
    throw HostConfigError(path + ": /marks: " + e.what());
  }
  return out;
}

}  // namespace storetrack::hostapp
