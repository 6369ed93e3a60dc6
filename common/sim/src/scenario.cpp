#include "storetrack/sim/scenario.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "storetrack/json/strict_reader.hpp"
#include "storetrack/json/text_file.hpp"

namespace storetrack::sim {
namespace {

using geometry::Vec3;
using jsonfile::Object;
using jsonfile::Range;
using jsonfile::Value;

Vec3 vec3(const Value& v) {
  const std::vector<double> x = v.numbers(3);
  return {x[0], x[1], x[2]};
}

void opt_vec3(Object& o, const char* key, Vec3& out) {
  if (const auto v = o.find(key)) out = vec3(*v);
}

// {"translation_m": [..], "ypr_deg": [yaw, pitch, roll]}
geometry::Transform pose(const Value& v) {
  Object o = v.object();
  geometry::Transform T = geometry::Transform::Identity();
  T.translation() = vec3(o.at("translation_m"));
  Vec3 ypr = Vec3::Zero();
  opt_vec3(o, "ypr_deg", ypr);
  o.finish();
  ypr *= M_PI / 180;
  T.linear() = geometry::rotation_from_ypr(ypr[0], ypr[1], ypr[2]);
  return T;
}

camera::Intrinsics parse_intrinsics(Object v) {
  camera::Intrinsics in;
  in.fx = v.at("fx").number(Range::above(0));
  in.fy = v.at("fy").number(Range::above(0));
  in.cx = v.at("cx").number();
  in.cy = v.at("cy").number();
  v.get("skew", in.skew);
  v.get("width", in.width, 16, 8192);
  v.get("height", in.height, 16, 8192);
  if (const auto d = v.find("dist")) {
    const std::vector<Value> k = d->array();
    if (k.size() != 4 && k.size() != 5 && k.size() != 8)
      d->fail("expected 4, 5 or 8 coefficients (k1 k2 p1 p2 [k3 [k4 k5 k6]])");
    for (std::size_t i = 0; i < k.size(); ++i)
      in.dist[i] = k[i].number();
  }
  v.finish();
  return in;
}

ScenarioKind parse_kind(const Value& v) {
  const std::string s = v.string();
  if (s == "store_separation") return ScenarioKind::kStoreSeparation;
  if (s == "pendulum") return ScenarioKind::kPendulum;
  if (s == "static") return ScenarioKind::kStatic;
  if (s == "scale_bars") return ScenarioKind::kScaleBars;
  v.fail("unknown kind '" + s + "' (store_separation, pendulum, static, scale_bars)");
}

void parse_timing(Object t, Scenario& sc) {
  t.get("frame_rate_hz", sc.frame_rate_hz, Range::closed(1, 100000));
  t.get("num_exposures", sc.num_exposures, 1, 1000000);
  t.get("exposure_ns", sc.exposure_ns, 1, 1000000000);
  t.get("start_tai_ns", sc.start_tai_ns, 0, INT64_MAX / 2);
  t.get("first_trigger_seq", sc.first_trigger_seq, 0, UINT32_MAX);
  t.get("ptp_offset_sigma_ns", sc.ptp_offset_sigma_ns, Range::closed(0, 1e9));
  if (const auto v = t.find("clock_state"))
    sc.clock_state = static_cast<time::ClockState>(v->integer(0, 3));
  if (sc.exposure_ns * 1e-9 * sc.frame_rate_hz > 1.0)
    t.at("exposure_ns").fail("exposure longer than the frame period");
  t.finish();
}

// {"start_s": t, "ramp_s": 0 (step) or the drift's duration, "rotation_deg": [x, y, z],
//  "translation_m": [x, y, z]} (camera frame).
CameraMotion parse_motion(Object m) {
  CameraMotion cm;
  cm.enabled = true;
  m.get("start_s", cm.start_s, Range::closed(0, 1e6));
  m.get("ramp_s", cm.ramp_s, Range::closed(0, 1e6));
  Vec3 rotation_deg = Vec3::Zero();
  opt_vec3(m, "rotation_deg", rotation_deg);
  cm.rotation_rad = rotation_deg * M_PI / 180;
  opt_vec3(m, "translation_m", cm.translation_m);
  if (rotation_deg.norm() > 10 || cm.translation_m.norm() > 0.1)
    m.at(rotation_deg.norm() > 10 ? "rotation_deg" : "translation_m")
        .fail("a mount shift above 10 deg or 0.1 m is not a small motion");
  m.finish();
  return cm;
}

CameraSetup parse_camera(const Value& v, std::size_t index) {
  Object c = v.object();
  CameraSetup cs;
  cs.camera_id = static_cast<int>(index);
  c.get("camera_id", cs.camera_id, 0, 254);
  c.get("unit_id", cs.unit_id, 0, 254);
  cs.intrinsics = parse_intrinsics(c.at("intrinsics").object());
  cs.position_p_m = vec3(c.at("position_p_m"));
  const Value look_at = c.at("look_at_p_m");
  cs.look_at_p_m = vec3(look_at);
  if ((cs.look_at_p_m - cs.position_p_m).norm() < 1e-6) look_at.fail("coincides with position_p_m");
  double roll_deg = 0;
  c.get("roll_deg", roll_deg, Range::closed(-360, 360));
  cs.roll_rad = roll_deg * M_PI / 180;
  c.get("trigger_latency_ns", cs.trigger_latency_ns, Range::closed(0, 1e8));
  c.get("latency_calibration_sigma_ns", cs.latency_calibration_sigma_ns, Range::closed(0, 1e8));
  c.get("trigger_jitter_sigma_ns", cs.trigger_jitter_sigma_ns, Range::closed(0, 1e8));
  if (const auto m = c.find("motion")) cs.motion = parse_motion(m->object());
  c.finish();
  return cs;
}

void parse_calibration_errors(Object v, CalibrationErrorModel& ce) {
  v.get("focal_px", ce.focal_px, Range::closed(0, 1e3));
  v.get("principal_point_px", ce.principal_point_px, Range::closed(0, 1e3));
  v.get("skew_px", ce.skew_px, Range::closed(0, 1e3));
  v.get("rotation_rad", ce.rotation_rad, Range::closed(0, 1));
  v.get("translation_m", ce.translation_m, Range::closed(0, 1));
  v.get("registration_rotation_rad", ce.registration_rotation_rad, Range::closed(0, 1));
  v.get("registration_translation_m", ce.registration_translation_m, Range::closed(0, 1));
  if (const auto d = v.find("distortion")) {
    const std::vector<Value> sigmas = d->array(8, 8);
    for (std::size_t i = 0; i < 8; ++i)
      ce.distortion[i] = sigmas[i].number(Range::at_least(0));
  }
  v.finish();
}

VibrationMode parse_vibration_mode(Object v) {
  VibrationMode m;
  v.get("frequency_hz", m.frequency_hz, Range::closed(0, 1e5));
  opt_vec3(v, "amplitude_rot_rad", m.amplitude_rot_rad);
  opt_vec3(v, "amplitude_trans_m", m.amplitude_trans_m);
  v.finish();
  return m;
}

void parse_optics(Object v, MarkOptics& o) {
  v.get("psf_sigma_px", o.psf_sigma_px, Range::closed(0.05, 50));
  v.get("flux_ref_e", o.flux_ref_e, Range::closed(0, 1e12));
  v.get("reference_distance_m", o.reference_distance_m, Range::closed(1e-3, 1e4));
  v.get("flux_distance_exponent", o.flux_distance_exponent, Range::closed(0, 6));
  v.get("min_incidence_cos", o.min_incidence_cos, Range::closed(0, 1));
  v.get("centroid_sigma_factor", o.centroid_sigma_factor, Range::closed(0.1, 100));
  v.get("min_sigma_px", o.min_sigma_px, Range::closed(0, 10));
  v.get("min_in_image_fraction", o.min_in_image_fraction, Range::closed(0, 1));
  if (const auto sv = v.find("sensor")) {
    Object s = sv->object();
    SensorModel& sm = o.sensor;
    s.get("background_e", sm.background_e, Range::closed(0, 1e7));
    s.get("read_noise_e", sm.read_noise_e, Range::closed(0, 1e5));
    s.get("gain_e_per_dn", sm.gain_e_per_dn, Range::closed(1e-3, 1e6));
    s.get("bits", sm.bits, 8, 16);
    sm.full_scale_dn = (1 << sm.bits) - 1;
    s.get("full_scale_dn", sm.full_scale_dn, 1, (1 << sm.bits) - 1);  // at most 2^bits - 1
    s.get("black_level_dn", sm.black_level_dn, Range::closed(0, 65535));
    s.finish();
  }
  v.finish();
}

void parse_store_shape(Object v, Scenario& sc) {
  v.get("radius_m", sc.store_shape.radius_m, Range::closed(0, 10));
  v.get("x_tail_m", sc.store_shape.x_tail_m);
  v.get("x_nose_m", sc.store_shape.x_nose_m);
  if (sc.store_shape.x_nose_m <= sc.store_shape.x_tail_m)
    v.value().fail_member("x_nose_m", "must be > x_tail_m");
  v.finish();
}

void parse_separation(Object v, SeparationMotion& s) {
  if (const auto t = v.find("T_p_s0")) s.T_p_s0 = pose(*t);
  v.get("release_time_s", s.release_time_s, Range::closed(0, 1e4));
  v.get("ejector_stroke_m", s.ejector_stroke_m, Range::closed(0, 10));
  v.get("ejector_duration_s", s.ejector_duration_s, Range::closed(1e-4, 10));
  opt_vec3(v, "accel_p_m_s2", s.accel_p_m_s2);
  opt_vec3(v, "rate_ypr_rad_s", s.rate_ypr_rad_s);
  opt_vec3(v, "accel_ypr_rad_s2", s.accel_ypr_rad_s2);
  v.finish();
}

void parse_pendulum(Object v, PendulumMotion& m) {
  v.get("l1_m", m.l1_m, Range::closed(1e-4, 100));
  v.get("l2_m", m.l2_m, Range::closed(1e-4, 100));
  v.get("mass_kg", m.mass_kg, Range::closed(1e-6, 1e4));
  v.get("damping_n_m_s", m.damping_n_m_s, Range::closed(0, 1e3));
  v.get("g_m_s2", m.g_m_s2, Range::closed(0, 100));
  double theta0_deg = m.theta0_rad * 180 / M_PI;
  v.get("theta0_deg", theta0_deg, Range::closed(-720, 720));
  m.theta0_rad = theta0_deg * M_PI / 180;
  v.get("theta_dot0_rad_s", m.theta_dot0_rad_s, Range::closed(-1e3, 1e3));
  v.get("release_time_s", m.release_time_s, Range::closed(0, 1e4));
  opt_vec3(v, "pivot_p_m", m.pivot_p_m);
  opt_vec3(v, "axis_p", m.axis_p);
  if (m.axis_p.norm() < 1e-9) v.at("axis_p").fail("must be non-zero");
  m.axis_p.normalize();
  v.finish();
}

void parse_scale_bar_layout(Object v, ScaleBarLayout& b) {
  opt_vec3(v, "centre_p_m", b.centre_p_m);
  opt_vec3(v, "size_m", b.size_m);
  v.get("span_fraction", b.span_fraction, Range::closed(0.05, 1));
  v.get("mark_sigma_m", b.mark_sigma_m, Range::closed(0, 1));
  v.get("mark_diameter_m", b.mark_diameter_m, Range::closed(1e-4, 1));
  if (b.size_m.minCoeff() <= 0) v.at("size_m").fail("must be > 0");
  v.finish();
}

Scenario read_scenario(const Value& value) {
  Object root = value.object();
  if (const auto f = root.find("format"); f && f->json() != "storetrack-scenario")
    f->fail("expected \"storetrack-scenario\"");
  if (const auto v = root.find("version"); v && v->json() != 1) v->fail("expected 1");
  root.known({"doc"});
  Scenario sc;
  sc.origin = value.file();
  sc.name = root.at("name").string();
  sc.kind = parse_kind(root.at("kind"));
  if (const auto v = root.find("timing")) parse_timing(v->object(), sc);
  if (const auto v = root.find("T_w_p")) sc.T_w_p = pose(*v);
  for (const Value& c : root.at("cameras").array(1, 8)) {
    CameraSetup cs = parse_camera(c, sc.cameras.size());
    for (const CameraSetup& other : sc.cameras)
      if (other.camera_id == cs.camera_id) c.fail_member("camera_id", "duplicate camera id");
    sc.cameras.push_back(cs);
  }
  if (const auto v = root.find("calibration_errors"))
    parse_calibration_errors(v->object(), sc.calibration);
  if (const auto v = root.find("vibration"))
    for (const Value& mode : v->array())
      sc.vibration.push_back(parse_vibration_mode(mode.object()));
  if (const auto v = root.find("optics")) parse_optics(v->object(), sc.optics);
  sc.pylon = survey::read_survey(root.at("pylon_survey"));
  if (sc.has_store()) sc.store = survey::read_survey(root.at("store_survey"));
  if (sc.kind == ScenarioKind::kPendulum)
    sc.pendulum = survey::read_survey(root.at("pendulum_survey"));
  root.known({"store_survey", "pendulum_survey"});  // not read by every kind
  if (const auto v = root.find("store_shape")) parse_store_shape(v->object(), sc);
  if (const auto v = root.find("separation")) parse_separation(v->object(), sc.separation);
  if (const auto v = root.find("pendulum")) parse_pendulum(v->object(), sc.pendulum_motion);
  if (const auto v = root.find("scale_bars")) parse_scale_bar_layout(v->object(), sc.scale_bars);
  root.finish();
  return sc;
}

}  // namespace

double CameraMotion::fraction(double t) const {
  if (!enabled || t < start_s) return 0;
  if (ramp_s <= 0) return 1;
  return std::min(1.0, (t - start_s) / ramp_s);
}

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
  try {
    const jsonfile::Document doc = jsonfile::Document::parse(json_text, origin);
    return read_scenario(doc.root());
  } catch (const jsonfile::FieldError& e) {
    throw ScenarioError(e.what());
  }
}

Scenario load_scenario(const std::string& path) {
  std::string text;
  try {
    text = jsonfile::read_text_file(path);
  } catch (const jsonfile::FileReadError& e) {
    throw ScenarioError(std::string(e.what()) + " (scenario file)");
  }
  return parse_scenario(text, path);
}

}  // namespace storetrack::sim
