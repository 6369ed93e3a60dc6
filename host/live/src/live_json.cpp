// The page's JSON: the snapshot (GET /api/snapshot and every event) and the scene.
#include <cmath>
#include <string>

#include <nlohmann/json.hpp>

#include "storetrack/live/live_coverage.hpp"
#include "storetrack/live/live_server.hpp"

namespace storetrack::live {

namespace {

using nlohmann::json;

// Pixels to 1/1000 px: the page draws them, the JSON stays small.
double milli(double v) {
  return std::round(v * 1000.0) / 1000.0;
}

// NaN and infinities become null (JSON has neither).
json number(double v) {
  return std::isfinite(v) ? json(v) : json(nullptr);
}

json aligner_json(const ingest::AlignerCounters& a) {
  return {{"observations_in", a.observations_in},
          {"observations_used", a.observations_used},
          {"exposures_complete", a.exposures_complete},
          {"exposures_partial_timeout", a.exposures_partial_timeout},
          {"exposures_partial_overflow", a.exposures_partial_overflow},
          {"exposures_dropped_too_few_cameras", a.exposures_dropped_too_few_cameras},
          {"exposures_dropped_numbering_unknown", a.exposures_dropped_numbering_unknown},
          {"dropped_unknown_camera", a.dropped_unknown_camera},
          {"dropped_spoofed", a.dropped_spoofed},
          {"dropped_invalid", a.dropped_invalid},
          {"dropped_time_out_of_range", a.dropped_time_out_of_range},
          {"dropped_duplicate", a.dropped_duplicate},
          {"dropped_late", a.dropped_late},
          {"dropped_time_mismatch", a.dropped_time_mismatch},
          {"dropped_quarantined", a.dropped_quarantined},
          {"dropped_too_few_cameras", a.dropped_too_few_cameras},
          {"dropped_numbering_unknown", a.dropped_numbering_unknown},
          {"sequence_offset_changes", a.sequence_offset_changes},
          {"sequence_restarts", a.sequence_restarts},
          {"camera_missing_total", a.camera_missing_total}};
}

json camera_counters_json(const ingest::CameraCounters& c) {
  return {{"received", c.received},
          {"used", c.used},
          {"missing", c.missing},
          {"time_mismatch", c.time_mismatch},
          {"late", c.late},
          {"duplicate", c.duplicate},
          {"spoofed", c.spoofed},
          {"quarantined", c.quarantined},
          {"offset_changes", c.offset_changes},
          {"sequence_offset", c.sequence_offset}};
}

// Surveyed marks of one body through its last valid pose into one camera: [[id, x, y], ...].
json expected_marks(const camera::CalibratedCamera* cam, const LiveBodyPose& pose,
                    const survey::RigidBodySurvey& body) {
  json out = json::array();
  if (!cam || !pose.valid) return out;
  const auto& in = cam->model.intrinsics();
  for (const auto& m : body.marks) {
    const auto px = camera::project_body_point(*cam, pose.T_w_b, m.p_body);
    if (!px || px->x() < -0.5 || px->y() < -0.5 || px->x() > in.width - 0.5 ||
        px->y() > in.height - 0.5)
      continue;  // behind the camera or outside its image
    out.push_back({m.id, milli(px->x()), milli(px->y())});
  }
  return out;
}

// Pixels to 1/10 px: an outline is drawn, not measured, and there are many of them.
double deci(double v) {
  return std::round(v * 10.0) / 10.0;
}

// The coverage overlay: per envelope pose the store marks' hull through the last valid pylon
// pose, [{"hull": [[x, y], ...], "leaves_image": bool}, ...]; empty without either.
json coverage_json(const camera::CalibratedCamera* cam, const LiveBodyPose& pylon,
                   const LiveScene& scene) {
  json out = json::array();
  if (!cam || !pylon.valid || scene.store_envelope_p.empty()) return out;
  for (const CoverageOutline& o :
       coverage_outlines(*cam, pylon.T_w_b, scene.store_envelope_p, scene.store)) {
    json hull = json::array();
    for (const geometry::Vec2& p : o.hull)
      hull.push_back({deci(p.x()), deci(p.y())});
    out.push_back({{"hull", std::move(hull)}, {"leaves_image", o.leaves_image}});
  }
  return out;
}

json camera_json(const LiveCamera& c, const LiveSnapshot& s, const LiveScene& scene) {
  json marks = json::array();
  for (int j = 0; j < c.mark_count; ++j) {
    const LiveMark& m = c.marks[static_cast<std::size_t>(j)];
    json jm = {{"x", milli(m.x_px)}, {"y", milli(m.y_px)}, {"id", m.id}};
    if (m.id >= 0) jm["body"] = std::string(1, m.body);
    if (m.has_residual) {
      jm["rx"] = milli(m.residual_x_px);
      jm["ry"] = milli(m.residual_y_px);
    }
    if (m.excluded) jm["excluded"] = true;
    marks.push_back(std::move(jm));
  }
  const camera::CalibratedCamera* cam = scene.rig.find(c.camera_id);
  json j = {{"camera_id", c.camera_id},
            {"unit_id", c.unit_id},
            {"delivered", c.delivered},
            {"mark_count", c.mark_count},
            {"marks", std::move(marks)},
            {"expected_pylon", expected_marks(cam, s.pylon, scene.pylon)},
            {"expected_store", expected_marks(cam, s.store, scene.store)},
            {"coverage", coverage_json(cam, s.pylon, scene)},
            {"counters", camera_counters_json(c.counters)}};
  if (c.last_seen_mono_ns != 0) {
    j["last_clock_state"] = c.last_clock_state;
    j["last_seen_age_ms"] =
        static_cast<double>(time::monotonic_now_ns() - c.last_seen_mono_ns) * 1e-6;
  }
  if (c.delivered) {
    j["trigger_seq"] = c.trigger_seq;
    j["exposure_start_tai_ns"] = c.exposure_start_tai_ns;
    j["exposure_duration_ns"] = c.exposure_duration_ns;
    j["clock_state"] = c.clock_state;
    j["flags"] = c.flags;
  }
  return j;
}

// A field at its schema "invalid" value (not available) becomes null.
template <class T>
json valid_or_null(T value, T invalid, double scale = 1) {
  return value == invalid ? json(nullptr) : json(static_cast<double>(value) * scale);
}

json unit_json(const LiveUnit& u, time::MonotonicNs now) {
  json j = {{"unit_id", u.unit_id}, {"heard", u.heard}, {"messages", u.messages}};
  if (!u.heard) return j;
  const msg::UnitHealth& h = u.health;
  namespace invalid = msg::unit_health_invalid;
  j["age_ms"] = static_cast<double>(now - u.heard_mono_ns) * 1e-6;
  j["clock_state"] = h.clock_state;
  j["ptp_offset_ns"] = valid_or_null(h.ptp_offset_ns, invalid::kPtpOffsetNs);
  j["sensor_temp_c"] = valid_or_null(h.sensor_temp_cdeg, invalid::kSensorTempCdeg, 0.01);
  j["board_temp_c"] = valid_or_null(h.board_temp_cdeg, invalid::kBoardTempCdeg, 0.01);
  j["frames_captured"] = valid_or_null(h.frames_captured, invalid::kFramesCaptured);
  j["frames_dropped"] = valid_or_null(h.frames_dropped, invalid::kFramesDropped);
  j["triggers_seen"] = valid_or_null(h.triggers_seen, invalid::kTriggersSeen);
  j["triggers_missing"] = valid_or_null(h.triggers_missing, invalid::kTriggersMissing);
  j["observations_sent"] = valid_or_null(h.observations_sent, invalid::kObservationsSent);
  j["link_tx_errors"] = valid_or_null(h.link_tx_errors, invalid::kLinkTxErrors);
  j["link_tx_dropped"] = valid_or_null(h.link_tx_dropped, invalid::kLinkTxDropped);
  j["status"] = h.status;
  return j;
}

json sample_json(const msg::FtiSample& s) {
  return {{"trigger_seq", s.trigger_seq},
          {"exposure_mid_tai_ns", s.exposure_mid_tai_ns},
          {"status", s.status},
          {"cameras_used", s.cameras_used},
          {"marks_used", s.marks_used},
          {"pylon_marks_used", s.pylon_marks_used},
          {"x_m", number(s.x_m)},
          {"y_m", number(s.y_m)},
          {"z_m", number(s.z_m)},
          {"yaw_rad", number(s.yaw_rad)},
          {"pitch_rad", number(s.pitch_rad)},
          {"roll_rad", number(s.roll_rad)},
          {"u_x_m", number(s.u_x_m)},
          {"u_y_m", number(s.u_y_m)},
          {"u_z_m", number(s.u_z_m)},
          {"u_yaw_rad", number(s.u_yaw_rad)},
          {"u_pitch_rad", number(s.u_pitch_rad)},
          {"u_roll_rad", number(s.u_roll_rad)},
          {"coverage_factor", number(s.coverage_factor)}};
}

}  // namespace

std::string snapshot_json(const LiveSnapshot& s, const LiveScene& scene,
                          const LiveServerCounters& server) {
  json cameras = json::array();
  for (int c = 0; c < s.camera_count; ++c)
    cameras.push_back(camera_json(s.cameras[static_cast<std::size_t>(c)], s, scene));
  json units = json::array();
  const time::MonotonicNs now = time::monotonic_now_ns();
  for (int u = 0; u < s.unit_count; ++u)
    units.push_back(unit_json(s.units[static_cast<std::size_t>(u)], now));
  json j = {{"publication", s.publication},
            {"age_ms", s.publication ? static_cast<double>(now - s.published_mono_ns) * 1e-6 : 0},
            {"exposure",
             {{"trigger_seq", s.trigger_seq},
              {"exposure_mid_tai_ns", s.exposure_mid_tai_ns},
              {"missing_camera_mask", s.missing_camera_mask},
              {"closed_by_timeout", s.closed_by_timeout},
              {"cameras_used", s.cameras_used},
              {"sample_written", s.sample_written}}},
            {"cameras", std::move(cameras)},
            {"units", std::move(units)},
            {"aligner", aligner_json(s.aligner)},
            {"totals",
             {{"exposures", s.totals.exposures},
              {"samples_written", s.totals.samples_written},
              {"valid_samples", s.totals.valid_samples},
              {"samples_withheld", s.totals.samples_withheld},
              {"health_messages", s.totals.health_messages}}},
            {"sample", s.has_sample ? sample_json(s.sample) : json(nullptr)},
            {"server",
             {{"clients", server.clients_now},
              {"clients_peak", server.clients_peak},
              {"clients_refused", server.clients_refused},
              {"clients_dropped", server.clients_dropped}}}};
  return j.dump();
}

std::string scene_json(const LiveScene& scene) {
  json cameras = json::array();
  for (const auto& c : scene.rig.cameras) {
    const auto& in = c.model.intrinsics();
    cameras.push_back({{"camera_id", c.camera_id},
                       {"unit_id", c.unit_id},
                       {"width", in.width},
                       {"height", in.height}});
  }
  auto ids = [](const survey::RigidBodySurvey& b) {
    json a = json::array();
    for (const auto& m : b.marks)
      a.push_back(m.id);
    return a;
  };
  return json{{"cameras", std::move(cameras)},
              {"pylon", {{"name", scene.pylon.name}, {"mark_ids", ids(scene.pylon)}}},
              {"store", {{"name", scene.store.name}, {"mark_ids", ids(scene.store)}}},
              {"store_envelope_poses", scene.store_envelope_p.size()}}
      .dump();
}

}  // namespace storetrack::live
