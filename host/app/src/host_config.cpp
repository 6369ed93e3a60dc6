#include "host_config.hpp"

#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

namespace storetrack::hostapp {
namespace {

nlohmann::json read_json(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw HostConfigError("cannot open '" + path + "'");
  std::stringstream ss;
  ss << in.rdbuf();
  try {
    return nlohmann::json::parse(ss.str());
  } catch (const nlohmann::json::exception& e) {
    throw HostConfigError(path + ": not valid JSON: " + e.what());
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

}  // namespace

void load_host_config(const std::string& path, HostConfig& c) {
  const nlohmann::json j = read_json(path);
  if (!j.is_object()) throw HostConfigError(path + ": top level must be an object");
  if (j.contains("udp")) {
    const auto& u = j["udp"];
    const std::string w = path + ": /udp";
    get(u, "bind", c.udp_bind, w);
    get(u, "port", c.udp_port, w);
    get(u, "group", c.udp_group, w);
    get(u, "interface", c.udp_interface, w);
  }
  get(j, "can_interfaces", c.can_interfaces, path + ": ");
  if (j.contains("aligner")) {
    const auto& a = j["aligner"];
    const std::string w = path + ": /aligner";
    double max_wait_ms = static_cast<double>(c.aligner.max_wait_ns) * 1e-6;
    get(a, "max_wait_ms", max_wait_ms, w);
    if (!(max_wait_ms > 0)) throw HostConfigError(w + "/max_wait_ms must be > 0");
    c.aligner.max_wait_ns = static_cast<std::int64_t>(max_wait_ms * 1e6);
    double spread_ms = static_cast<double>(c.aligner.max_mid_time_spread_ns) * 1e-6;
    get(a, "max_mid_time_spread_ms", spread_ms, w);
    c.aligner.max_mid_time_spread_ns = static_cast<std::int64_t>(spread_ms * 1e6);
    get(a, "max_pending", c.aligner.max_pending, w);
    get(a, "min_cameras", c.aligner.min_cameras, w);
  }
  if (j.contains("processor")) {
    const auto& p = j["processor"];
    const std::string w = path + ": /processor";
    int store_id = c.processor.store_id;
    get(p, "store_id", store_id, w);
    if (store_id < 0 || store_id > 254) throw HostConfigError(w + "/store_id must be 0..254");
    c.processor.store_id = static_cast<std::uint8_t>(store_id);
    get(p, "coverage_factor", c.processor.coverage_factor, w);
    get(p, "min_cameras_per_mark", c.processor.min_cameras_per_mark, w);
    get(p, "min_pose_marks", c.processor.min_pose_marks, w);
    get(p, "reference_camera_id", c.processor.reference_camera_id, w);
    get(p, "rigid_false_alarm_probability", c.processor.rigid_false_alarm_probability, w);
    get(p, "max_pose_rotation_sigma_rad", c.processor.max_pose_rotation_sigma_rad, w);
    if (!(c.processor.max_pose_rotation_sigma_rad > 0))
      throw HostConfigError(w + "/max_pose_rotation_sigma_rad must be > 0");
  }
  if (j.contains("pose_tracker")) {
    // Extrapolation of T_p_s over short gaps (host/pipeline PoseTracker, docs/uncertainty.md).
    const auto& t = j["pose_tracker"];
    const std::string w = path + ": /pose_tracker";
    auto& pt = c.pose_tracker;
    get(t, "max_gap_s", pt.max_gap_s, w);
    get(t, "max_velocity_baseline_s", pt.max_velocity_baseline_s, w);
    get(t, "accel_sigma_m_s2", pt.accel_sigma_m_s2, w);
    get(t, "angular_accel_sigma_rad_s2", pt.angular_accel_sigma_rad_s2, w);
    if (!(pt.max_gap_s >= 0) || !(pt.max_velocity_baseline_s > 0) || !(pt.accel_sigma_m_s2 > 0) ||
        !(pt.angular_accel_sigma_rad_s2 > 0))
      throw HostConfigError(w + ": max_gap_s must be >= 0 (0: never extrapolate), the others > 0");
  }
  if (j.contains("identifier")) {
    // Mark identification (host/match MarkMatcher, docs/matching.md).
    const auto& i = j["identifier"];
    const std::string w = path + ": /identifier";
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
  }
  if (j.contains("chapter10")) {
    const auto& o = j["chapter10"];
    const std::string w = path + ": /chapter10";
    get(o, "max_messages_per_packet", c.ch10.max_messages_per_packet, w);
    get(o, "data_checksum", c.ch10.data_checksum, w);
    get(o, "test_point", c.ch10.test_point, w);
  }
}

std::map<int, geometry::Vec3> load_initial_marks(const std::string& path) {
  const nlohmann::json j = read_json(path);
  std::map<int, geometry::Vec3> out;
  try {
    for (const auto& m : j.at("marks")) {
      const auto p = m.at("p_w_m").get<std::vector<double>>();
      if (p.size() != 3) throw HostConfigError(path + ": /marks/p_w_m needs 3 values");
      out[m.at("id").get<int>()] = geometry::Vec3(p[0], p[1], p[2]);
    }
  } catch (const nlohmann::json::exception& e) {
    throw HostConfigError(path + ": /marks: " + e.what());
  }
  return out;
}

}  // namespace storetrack::hostapp
