#include "storetrack/sim/scenario.hpp"

#include <cmath>
#include <fstream>
#include <initializer_list>
#include <sstream>

#include <nlohmann/json.hpp>

namespace storetrack::sim {
namespace {

using geometry::Vec3;
using nlohmann::json;

// Field access that names the file and JSON path in every error.
class Reader {
 public:
  explicit Reader(std::string origin) : origin_(std::move(origin)) {}

  [[noreturn]] void fail(const std::string& path, const std::string& why) const {
    throw ScenarioError(origin_ + ": field '" + path + "': " + why);
  }

  void check_keys(const json& obj, const std::string& path,
                  std::initializer_list<const char*> allowed) const {
    if (!obj.is_object()) fail(path, "expected an object");
    for (auto it = obj.begin(); it != obj.end(); ++it) {
      bool ok = false;
      for (const char* a : allowed)
        ok = ok || it.key() == a;
      if (!ok) fail(path + "." + it.key(), "unknown field");
    }
  }

  const json* find(const json& obj, const char* key) const {
    const auto it = obj.find(key);
    return it == obj.end() ? nullptr : &*it;
  }

  const json& require(const json& obj, const std::string& path, const char* key) const {
    const json* v = find(obj, key);
    if (!v) fail(path + "." + key, "missing");
    return *v;
  }

  double number(const json& v, const std::string& path) const {
    if (!v.is_number()) fail(path, "expected a number");
    const double d = v.get<double>();
    if (!std::isfinite(d)) fail(path, "not finite");
    return d;
  }

  void opt(const json& obj, const std::string& path, const char* key, double& out,
           double min = -INFINITY, double max = INFINITY) const {
    if (const json* v = find(obj, key)) {
      out = number(*v, path + "." + key);
      if (out < min || out > max) {
        fail(path + "." + key,
             "out of range [" + std::to_string(min) + ", " + std::to_string(max) + "]");
      }
    }
  }

  void opt_int(const json& obj, const std::string& path, const char* key, long long& out,
               long long min, long long max) const {
    if (const json* v = find(obj, key)) {
      if (!v->is_number_integer()) fail(path + "." + key, "expected an integer");
      out = v->get<long long>();
      if (out < min || out > max) fail(path + "." + key, "out of range");
    }
  }

  template <typename Int>
  void opt_int(const json& obj, const std::string& path, const char* key, Int& out, long long min,
               long long max) const {
    long long v = static_cast<long long>(out);
    opt_int(obj, path, key, v, min, max);
    out = static_cast<Int>(v);
  }

  Vec3 vec3(const json& v, const std::string& path) const {
    if (!v.is_array() || v.size() != 3) fail(path, "expected [x, y, z]");
    return {number(v[0], path + "[0]"), number(v[1], path + "[1]"), number(v[2], path + "[2]")};
  }

  void opt_vec3(const json& obj, const std::string& path, const char* key, Vec3& out) const {
    if (const json* v = find(obj, key)) out = vec3(*v, path + "." + key);
  }

  // {"translation_m": [..], "ypr_deg": [yaw, pitch, roll]}
  geometry::Transform pose(const json& v, const std::string& path) const {
    check_keys(v, path, {"translation_m", "ypr_deg"});
    geometry::Transform T = geometry::Transform::Identity();
    T.translation() = vec3(require(v, path, "translation_m"), path + ".translation_m");
    Vec3 ypr = Vec3::Zero();
    opt_vec3(v, path, "ypr_deg", ypr);
    ypr *= M_PI / 180;
    T.linear() = geometry::rotation_from_ypr(ypr[0], ypr[1], ypr[2]);
    return T;
  }

  survey::RigidBodySurvey survey(const json& v, const std::string& path) const {
    try {
      return survey::parse_survey(v.dump(), origin_ + ": " + path);
    } catch (const survey::SurveyFileError& e) {
      throw ScenarioError(e.what());
    }
  }

 private:
  std::string origin_;
};

camera::Intrinsics parse_intrinsics(const Reader& r, const json& v, const std::string& path) {
  r.check_keys(v, path, {"fx", "fy", "cx", "cy", "skew", "dist", "width", "height"});
  camera::Intrinsics in;
  in.fx = r.number(r.require(v, path, "fx"), path + ".fx");
  in.fy = r.number(r.require(v, path, "fy"), path + ".fy");
  in.cx = r.number(r.require(v, path, "cx"), path + ".cx");
  in.cy = r.number(r.require(v, path, "cy"), path + ".cy");
  r.opt(v, path, "skew", in.skew);
  r.opt_int(v, path, "width", in.width, 16, 8192);
  r.opt_int(v, path, "height", in.height, 16, 8192);
  if (in.fx <= 0 || in.fy <= 0) r.fail(path + ".fx", "focal lengths must be > 0");
  if (const json* d = r.find(v, "dist")) {
    if (!d->is_array() || d->size() > 8 || (d->size() != 5 && d->size() != 8 && d->size() != 4)) {
      r.fail(path + ".dist", "expected 4, 5 or 8 coefficients (k1 k2 p1 p2 [k3 [k4 k5 k6]])");
    }
    for (std::size_t i = 0; i < d->size(); ++i) {
      in.dist[i] = r.number((*d)[i], path + ".dist[" + std::to_string(i) + "]");
    }
  }
  return in;
}

ScenarioKind parse_kind(const Reader& r, const json& v) {
  if (!v.is_string()) r.fail("kind", "expected a string");
  const std::string s = v.get<std::string>();
  if (s == "store_separation") return ScenarioKind::kStoreSeparation;
  if (s == "pendulum") return ScenarioKind::kPendulum;
  if (s == "static") return ScenarioKind::kStatic;
  if (s == "scale_bars") return ScenarioKind::kScaleBars;
  r.fail("kind", "unknown kind '" + s + "' (store_separation, pendulum, static, scale_bars)");
}

}  // namespace

const char* to_string(ScenarioKind kind) {
  switch (kind) {
    case ScenarioKind::kStoreSeparation:
      return "store_separation";
    case ScenarioKind::kPendulum:
      return "pendulum";
    case ScenarioKind::kStatic:
      return "static";
    case ScenarioKind::kScaleBars:
      return "scale_bars";
  }
  return "unknown";
}

Scenario parse_scenario(const std::string& json_text, const std::string& origin) {
  json root;
  try {
    root = json::parse(json_text);
  } catch (const json::parse_error& e) {
    throw ScenarioError(origin + ": not valid JSON: " + e.what());
  }
  const Reader r(origin);
  r.check_keys(root, "$",
               {"format", "version", "name", "kind", "doc", "timing", "T_w_p", "cameras",
                "calibration_errors", "vibration", "optics", "pylon_survey", "store_survey",
                "pendulum_survey", "store_shape", "separation", "pendulum", "scale_bars"});
  if (const json* f = r.find(root, "format"); f && *f != "storetrack-scenario") {
    r.fail("format", "expected \"storetrack-scenario\"");
  }
  if (const json* v = r.find(root, "version"); v && *v != 1) r.fail("version", "expected 1");
  Scenario sc;
  sc.origin = origin;
  const json& name = r.require(root, "$", "name");
  if (!name.is_string()) r.fail("name", "expected a string");
  sc.name = name.get<std::string>();
  sc.kind = parse_kind(r, r.require(root, "$", "kind"));

  if (const json* t = r.find(root, "timing")) {
    const std::string p = "timing";
    r.check_keys(*t, p,
                 {"frame_rate_hz", "num_exposures", "exposure_ns", "start_tai_ns",
                  "first_trigger_seq", "ptp_offset_sigma_ns", "clock_state"});
    r.opt(*t, p, "frame_rate_hz", sc.frame_rate_hz, 1, 100000);
    r.opt_int(*t, p, "num_exposures", sc.num_exposures, 1, 1000000);
    r.opt_int(*t, p, "exposure_ns", sc.exposure_ns, 1, 1000000000);
    r.opt_int(*t, p, "start_tai_ns", sc.start_tai_ns, 0, INT64_MAX / 2);
    r.opt_int(*t, p, "first_trigger_seq", sc.first_trigger_seq, 0, UINT32_MAX);
    r.opt(*t, p, "ptp_offset_sigma_ns", sc.ptp_offset_sigma_ns, 0, 1e9);
    int clock = static_cast<int>(sc.clock_state);
    r.opt_int(*t, p, "clock_state", clock, 0, 3);
    sc.clock_state = static_cast<time::ClockState>(clock);
    if (sc.exposure_ns * 1e-9 * sc.frame_rate_hz > 1.0) {
      r.fail("timing.exposure_ns", "exposure longer than the frame period");
    }
  }
  if (const json* v = r.find(root, "T_w_p")) sc.T_w_p = r.pose(*v, "T_w_p");

  const json& cams = r.require(root, "$", "cameras");
  if (!cams.is_array() || cams.empty() || cams.size() > 8) {
    r.fail("cameras", "expected an array of 1..8 cameras");
  }
  for (std::size_t i = 0; i < cams.size(); ++i) {
    const std::string p = "cameras[" + std::to_string(i) + "]";
    const json& c = cams[i];
    r.check_keys(c, p,
                 {"camera_id", "unit_id", "intrinsics", "position_p_m", "look_at_p_m", "roll_deg",
                  "trigger_latency_ns", "latency_calibration_sigma_ns", "trigger_jitter_sigma_ns"});
    CameraSetup cs;
    cs.camera_id = static_cast<int>(i);
    r.opt_int(c, p, "camera_id", cs.camera_id, 0, 254);
    r.opt_int(c, p, "unit_id", cs.unit_id, 0, 254);
    cs.intrinsics = parse_intrinsics(r, r.require(c, p, "intrinsics"), p + ".intrinsics");
    cs.position_p_m = r.vec3(r.require(c, p, "position_p_m"), p + ".position_p_m");
    cs.look_at_p_m = r.vec3(r.require(c, p, "look_at_p_m"), p + ".look_at_p_m");
    if ((cs.look_at_p_m - cs.position_p_m).norm() < 1e-6) {
      r.fail(p + ".look_at_p_m", "coincides with position_p_m");
    }
    double roll_deg = 0;
    r.opt(c, p, "roll_deg", roll_deg, -360, 360);
    cs.roll_rad = roll_deg * M_PI / 180;
    r.opt(c, p, "trigger_latency_ns", cs.trigger_latency_ns, 0, 1e8);
    r.opt(c, p, "latency_calibration_sigma_ns", cs.latency_calibration_sigma_ns, 0, 1e8);
    r.opt(c, p, "trigger_jitter_sigma_ns", cs.trigger_jitter_sigma_ns, 0, 1e8);
    for (const CameraSetup& other : sc.cameras) {
      if (other.camera_id == cs.camera_id) r.fail(p + ".camera_id", "duplicate camera id");
    }
    sc.cameras.push_back(cs);
  }

  if (const json* v = r.find(root, "calibration_errors")) {
    const std::string p = "calibration_errors";
    r.check_keys(*v, p,
                 {"focal_px", "principal_point_px", "skew_px", "distortion", "rotation_rad",
                  "translation_m", "registration_rotation_rad", "registration_translation_m"});
    CalibrationErrorModel& ce = sc.calibration;
    r.opt(*v, p, "focal_px", ce.focal_px, 0, 1e3);
    r.opt(*v, p, "principal_point_px", ce.principal_point_px, 0, 1e3);
    r.opt(*v, p, "skew_px", ce.skew_px, 0, 1e3);
    r.opt(*v, p, "rotation_rad", ce.rotation_rad, 0, 1);
    r.opt(*v, p, "translation_m", ce.translation_m, 0, 1);
    r.opt(*v, p, "registration_rotation_rad", ce.registration_rotation_rad, 0, 1);
    r.opt(*v, p, "registration_translation_m", ce.registration_translation_m, 0, 1);
    if (const json* d = r.find(*v, "distortion")) {
      if (!d->is_array() || d->size() != 8) r.fail(p + ".distortion", "expected 8 sigmas");
      for (std::size_t i = 0; i < 8; ++i) {
        ce.distortion[i] = r.number((*d)[i], p + ".distortion[" + std::to_string(i) + "]");
        if (ce.distortion[i] < 0) r.fail(p + ".distortion", "sigmas must be >= 0");
      }
    }
  }
  if (const json* v = r.find(root, "vibration")) {
    if (!v->is_array()) r.fail("vibration", "expected an array of modes");
    for (std::size_t i = 0; i < v->size(); ++i) {
      const std::string p = "vibration[" + std::to_string(i) + "]";
      r.check_keys((*v)[i], p, {"frequency_hz", "amplitude_rot_rad", "amplitude_trans_m"});
      VibrationMode m;
      r.opt((*v)[i], p, "frequency_hz", m.frequency_hz, 0, 1e5);
      r.opt_vec3((*v)[i], p, "amplitude_rot_rad", m.amplitude_rot_rad);
      r.opt_vec3((*v)[i], p, "amplitude_trans_m", m.amplitude_trans_m);
      sc.vibration.push_back(m);
    }
  }
  if (const json* v = r.find(root, "optics")) {
    const std::string p = "optics";
    r.check_keys(
        *v, p,
        {"sensor", "psf_sigma_px", "flux_ref_e", "reference_distance_m", "flux_distance_exponent",
         "min_incidence_cos", "centroid_sigma_factor", "min_sigma_px", "min_in_image_fraction"});
    MarkOptics& o = sc.optics;
    r.opt(*v, p, "psf_sigma_px", o.psf_sigma_px, 0.05, 50);
    r.opt(*v, p, "flux_ref_e", o.flux_ref_e, 0, 1e12);
    r.opt(*v, p, "reference_distance_m", o.reference_distance_m, 1e-3, 1e4);
    r.opt(*v, p, "flux_distance_exponent", o.flux_distance_exponent, 0, 6);
    r.opt(*v, p, "min_incidence_cos", o.min_incidence_cos, 0, 1);
    r.opt(*v, p, "centroid_sigma_factor", o.centroid_sigma_factor, 0.1, 100);
    r.opt(*v, p, "min_sigma_px", o.min_sigma_px, 0, 10);
    r.opt(*v, p, "min_in_image_fraction", o.min_in_image_fraction, 0, 1);
    if (const json* s = r.find(*v, "sensor")) {
      const std::string q = p + ".sensor";
      r.check_keys(*s, q,
                   {"background_e", "read_noise_e", "gain_e_per_dn", "full_scale_dn", "bits",
                    "black_level_dn"});
      SensorModel& sm = o.sensor;
      r.opt(*s, q, "background_e", sm.background_e, 0, 1e7);
      r.opt(*s, q, "read_noise_e", sm.read_noise_e, 0, 1e5);
      r.opt(*s, q, "gain_e_per_dn", sm.gain_e_per_dn, 1e-3, 1e6);
      r.opt_int(*s, q, "bits", sm.bits, 8, 16);
      sm.full_scale_dn = (1 << sm.bits) - 1;
      r.opt_int(*s, q, "full_scale_dn", sm.full_scale_dn, 1, 65535);
      r.opt(*s, q, "black_level_dn", sm.black_level_dn, 0, 65535);
      if (sm.full_scale_dn > (1 << sm.bits) - 1) r.fail(q + ".full_scale_dn", "exceeds 2^bits-1");
    }
  }

  sc.pylon = r.survey(r.require(root, "$", "pylon_survey"), "pylon_survey");
  if (sc.has_store()) {
    sc.store = r.survey(r.require(root, "$", "store_survey"), "store_survey");
  }
  if (sc.kind == ScenarioKind::kPendulum) {
    sc.pendulum = r.survey(r.require(root, "$", "pendulum_survey"), "pendulum_survey");
  }
  if (const json* v = r.find(root, "store_shape")) {
    r.check_keys(*v, "store_shape", {"radius_m", "x_tail_m", "x_nose_m"});
    r.opt(*v, "store_shape", "radius_m", sc.store_shape.radius_m, 0, 10);
    r.opt(*v, "store_shape", "x_tail_m", sc.store_shape.x_tail_m);
    r.opt(*v, "store_shape", "x_nose_m", sc.store_shape.x_nose_m);
    if (sc.store_shape.x_nose_m <= sc.store_shape.x_tail_m) {
      r.fail("store_shape.x_nose_m", "must be > x_tail_m");
    }
  }
  if (const json* v = r.find(root, "separation")) {
    const std::string p = "separation";
    r.check_keys(*v, p,
                 {"T_p_s0", "release_time_s", "ejector_stroke_m", "ejector_duration_s",
                  "accel_p_m_s2", "rate_ypr_rad_s", "accel_ypr_rad_s2"});
    SeparationMotion& s = sc.separation;
    if (const json* t = r.find(*v, "T_p_s0")) s.T_p_s0 = r.pose(*t, p + ".T_p_s0");
    r.opt(*v, p, "release_time_s", s.release_time_s, 0, 1e4);
    r.opt(*v, p, "ejector_stroke_m", s.ejector_stroke_m, 0, 10);
    r.opt(*v, p, "ejector_duration_s", s.ejector_duration_s, 1e-4, 10);
    r.opt_vec3(*v, p, "accel_p_m_s2", s.accel_p_m_s2);
    r.opt_vec3(*v, p, "rate_ypr_rad_s", s.rate_ypr_rad_s);
    r.opt_vec3(*v, p, "accel_ypr_rad_s2", s.accel_ypr_rad_s2);
  }
  if (const json* v = r.find(root, "pendulum")) {
    const std::string p = "pendulum";
    r.check_keys(*v, p,
                 {"l1_m", "l2_m", "mass_kg", "damping_n_m_s", "g_m_s2", "theta0_deg",
                  "theta_dot0_rad_s", "release_time_s", "pivot_p_m", "axis_p"});
    PendulumMotion& m = sc.pendulum_motion;
    r.opt(*v, p, "l1_m", m.l1_m, 1e-4, 100);
    r.opt(*v, p, "l2_m", m.l2_m, 1e-4, 100);
    r.opt(*v, p, "mass_kg", m.mass_kg, 1e-6, 1e4);
    r.opt(*v, p, "damping_n_m_s", m.damping_n_m_s, 0, 1e3);
    r.opt(*v, p, "g_m_s2", m.g_m_s2, 0, 100);
    double theta0_deg = m.theta0_rad * 180 / M_PI;
    r.opt(*v, p, "theta0_deg", theta0_deg, -720, 720);
    m.theta0_rad = theta0_deg * M_PI / 180;
    r.opt(*v, p, "theta_dot0_rad_s", m.theta_dot0_rad_s, -1e3, 1e3);
    r.opt(*v, p, "release_time_s", m.release_time_s, 0, 1e4);
    r.opt_vec3(*v, p, "pivot_p_m", m.pivot_p_m);
    r.opt_vec3(*v, p, "axis_p", m.axis_p);
    if (m.axis_p.norm() < 1e-9) r.fail(p + ".axis_p", "must be non-zero");
    m.axis_p.normalize();
  }
  if (const json* v = r.find(root, "scale_bars")) {
    const std::string p = "scale_bars";
    r.check_keys(*v, p,
                 {"centre_p_m", "size_m", "span_fraction", "mark_sigma_m", "mark_diameter_m"});
    ScaleBarLayout& b = sc.scale_bars;
    r.opt_vec3(*v, p, "centre_p_m", b.centre_p_m);
    r.opt_vec3(*v, p, "size_m", b.size_m);
    r.opt(*v, p, "span_fraction", b.span_fraction, 0.05, 1);
    r.opt(*v, p, "mark_sigma_m", b.mark_sigma_m, 0, 1);
    r.opt(*v, p, "mark_diameter_m", b.mark_diameter_m, 1e-4, 1);
    if (b.size_m.minCoeff() <= 0) r.fail(p + ".size_m", "must be > 0");
  }
  return sc;
}

Scenario load_scenario(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw ScenarioError(path + ": cannot open scenario file");
  std::stringstream buf;
  buf << in.rdbuf();
  return parse_scenario(buf.str(), path);
}

}  // namespace storetrack::sim
