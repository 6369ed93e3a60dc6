#include "noise_floor_command.hpp"

#include <fmt/format.h>

#include <cmath>
#include <fstream>

#include "storetrack/survey/survey.hpp"

namespace storetrack::evalapp {
namespace {

constexpr const char* kWorldAxes[3] = {"x", "y", "z"};
constexpr const char* kRigAxes[3] = {"in_plane_1", "in_plane_2", "out_of_plane"};
constexpr double kDeg = 180.0 / M_PI;

nlohmann::json axis_json(const eval::AxisNoise& a) {
  return {{"temporal_sd_m", a.temporal_sd_m},
          {"bias_m", a.bias_m},
          {"u_bias_m", a.u_bias_m},
          {"bias_within_k_u", a.bias_within_k_u},
          {"u_stated_m", a.u_stated_m},
          {"u_centroid_m", a.u_centroid_m},
          {"ratio", a.ratio},
          {"agrees", a.agrees}};
}

nlohmann::json summary_json(const eval::AxisNoiseSummary& s) {
  return {{"temporal_sd_mean_m", s.temporal_sd_mean_m},
          {"temporal_sd_rms_m", s.temporal_sd_rms_m},
          {"spatial_sd_mean_m", s.spatial_sd_mean_m},
          {"bias_mean_m", s.bias_mean_m},
          {"bias_rms_m", s.bias_rms_m},
          {"bias_max_abs_m", s.bias_max_abs_m},
          {"u_stated_rms_m", s.u_stated_rms_m},
          {"u_centroid_rms_m", s.u_centroid_rms_m},
          {"pooled_ratio", s.pooled_ratio},
          {"pooled_interval", {s.pooled_low, s.pooled_high}},
          {"pooled_dof", s.pooled_dof},
          {"agreeing_marks", s.agreeing_marks},
          {"bias_within_k_u", s.bias_within_k_u}};
}

nlohmann::json marks_json(const eval::NoiseFloorResult& r) {
  nlohmann::json marks = nlohmann::json::array();
  for (const eval::MarkNoise& m : r.marks) {
    nlohmann::json jm = {{"mark_id", m.mark_id},
                         {"body", std::string(1, m.body)},
                         {"samples", m.samples},
                         {"ratio_interval", {m.ratio_low, m.ratio_high}},
                         {"mean_p_w_m", {m.mean_p_w.x(), m.mean_p_w.y(), m.mean_p_w.z()}}};
    for (int a = 0; a < 3; ++a) {
      jm[kWorldAxes[a]] = axis_json(m.world[static_cast<size_t>(a)]);
      if (r.has_rig) jm[kRigAxes[a]] = axis_json(m.rig[static_cast<size_t>(a)]);
    }
    marks.push_back(jm);
  }
  return marks;
}

nlohmann::json image_json(const eval::NoiseFloorResult& r) {
  nlohmann::json cams = nlohmann::json::array();
  for (const eval::CameraImageNoise& c : r.cameras) {
    nlohmann::json jc = {{"camera_id", c.camera_id},
                         {"marks", c.marks},
                         {"observations", c.observations},
                         {"without_pixel", c.without_pixel},
                         {"pooled_dof", c.pooled_dof}};
    for (int a = 0; a < 2; ++a) {
      const eval::ImageAxisNoise& x = c.axis[static_cast<size_t>(a)];
      jc[a == 0 ? "u" : "v"] = {{"residual_rms_px", x.residual_rms_px},
                                {"temporal_sd_mean_px", x.temporal_sd_mean_px},
                                {"sigma_rms_px", x.sigma_rms_px},
                                {"pooled_ratio", x.pooled_ratio},
                                {"pooled_interval", {x.pooled_low, x.pooled_high}},
                                {"agrees", x.agrees}};
    }
    cams.push_back(jc);
  }
  return cams;
}

nlohmann::json geometry_json(const eval::NoiseFloorResult& r) {
  nlohmann::json stereo = nlohmann::json::array();
  for (const eval::StereoAngle& s : r.stereo_angles)
    stereo.push_back({{"mark_id", s.mark_id},
                      {"camera_a", s.camera_a},
                      {"camera_b", s.camera_b},
                      {"stereo_angle_rad", s.stereo_angle_rad},
                      {"theta_a_rad", s.theta_a_rad},
                      {"theta_b_rad", s.theta_b_rad},
                      {"error_rad", s.error_rad}});
  nlohmann::json distances = nlohmann::json::array();
  for (const eval::DistanceError& d : r.distances)
    distances.push_back({{"id_a", d.id_a},
                         {"id_b", d.id_b},
                         {"samples", d.samples},
                         {"reference_m", d.reference_m},
                         {"measured_m", d.measured_m},
                         {"temporal_sd_m", d.temporal_sd_m},
                         {"u_measured_m", d.u_measured_m},
                         {"error_percent", d.error_percent},
                         {"u_error_percent", d.u_error_percent}});
  return {{"stereo_angles", stereo}, {"distances", distances}};
}

/// The per-axis table of seed 002's noise floor (variance error mu_T, mu_S; bias error).
void print_axis_rows(const std::array<eval::AxisNoiseSummary, 3>& summary,
                     const char* const names[3], bool stated, std::ostream& out) {
  for (int a = 0; a < 3; ++a) {
    const eval::AxisNoiseSummary& s = summary[static_cast<size_t>(a)];
    const std::string ratio =
        s.pooled_ratio > 0
            ? fmt::format("{:.3f} [{:.3f}, {:.3f}]", s.pooled_ratio, s.pooled_low, s.pooled_high)
            : std::string("n/a");
    out << fmt::format(
        "  {:>12}  {:>9.4f}  {:>9.4f}  {:>9.4f}  {:>9.4f}  {:>9.4f}  {:>10}  {:>9}  {}\n", names[a],
        s.temporal_sd_mean_m * 1e3, s.spatial_sd_mean_m * 1e3, s.bias_mean_m * 1e3,
        s.bias_rms_m * 1e3, s.bias_max_abs_m * 1e3,
        s.u_centroid_rms_m > 0 ? fmt::format("{:.4f}", s.u_centroid_rms_m * 1e3) : std::string("-"),
        stated ? fmt::format("{:.4f}", s.u_stated_rms_m * 1e3) : std::string("-"), ratio);
  }
}

void print_geometry(const eval::NoiseFloorResult& r, std::ostream& out) {
  if (!r.image_coordinates_note.empty()) out << r.image_coordinates_note << "\n";
  if (!r.cameras.empty()) {
    out << "image-coordinate error per camera [px]: residual RMS u v, centroid sd over time "
           "(mean over marks) u v, stated sigma (RMS), pooled sd/sigma u v [interval]\n";
    for (const eval::CameraImageNoise& c : r.cameras)
      out << fmt::format(
          "  camera {:>3} ({:>2} marks)  {:.4f} {:.4f}   {:.4f} {:.4f}   {:.4f}   {:.3f} {:.3f} "
          "[{:.3f}, {:.3f}]\n",
          c.camera_id, c.marks, c.axis[0].residual_rms_px, c.axis[1].residual_rms_px,
          c.axis[0].temporal_sd_mean_px, c.axis[1].temporal_sd_mean_px, c.axis[0].sigma_rms_px,
          c.axis[0].pooled_ratio, c.axis[1].pooled_ratio, c.axis[0].pooled_low,
          c.axis[0].pooled_high);
  }
  if (!r.stereo_angles.empty()) {
    out << "stereo angle per mark and camera pair [deg]: stereo angle, e_theta = theta_a - "
           "theta_b (seed 002 eq. 3, theta from the out-of-plane direction)\n";
    for (const eval::StereoAngle& s : r.stereo_angles)
      out << fmt::format("  mark {:>4} cameras {}-{}  {:>7.2f}  {:>7.2f}\n", s.mark_id, s.camera_a,
                         s.camera_b, s.stereo_angle_rad * kDeg, s.error_rad * kDeg);
  }
  out << fmt::format(
      "reconstruction error of surveyed distances (seed 002 eq. 4) [mm, %]: D, measured, "
      "E +- U (k = {:g})\n",
      r.options.coverage_factor);
  double max_abs = 0, mean_abs = 0;
  for (const eval::DistanceError& d : r.distances) {
    out << fmt::format("  {:>4}-{:<4}  {:>9.3f}  {:>9.3f}  {:>8.4f} +- {:.4f} %\n", d.id_a, d.id_b,
                       d.reference_m * 1e3, d.measured_m * 1e3, d.error_percent,
                       r.options.coverage_factor * d.u_error_percent);
    max_abs = std::max(max_abs, std::abs(d.error_percent));
    mean_abs += std::abs(d.error_percent) / static_cast<double>(r.distances.size());
  }
  out << fmt::format("  {} pairs: max |E| {:.4f} %, mean |E| {:.4f} %\n", r.distances.size(),
                     max_abs, mean_abs);
}

}  // namespace

void print_noise_floor(const eval::NoiseFloorResult& r, std::ostream& out) {
  out << fmt::format(
      "storetrack-eval noise-floor: {} exposures over {:.3f} s, {} marks of body '{}' (seed 002 "
      "noise floor; k = {:g}; s/u in its {:g} % chi-square interval)\n",
      r.exposures, r.duration_s, r.marks.size(), r.options.bodies(), r.options.coverage_factor,
      100 * r.options.agreement_level);
  const std::string header =
      "          axis  temporal   spatial   bias       bias       bias       u_centroid  "
      "u_stated   s/u_centroid pooled [interval]\n"
      "                mu_T (sd)  mu_S (sd)  (mean)     (RMS)      (max |.|)  (RMS)       (RMS)\n";
  out << "variance and bias error per axis [mm] (seed 002 noise floor), world frame:\n" << header;
  print_axis_rows(r.world_summary, kWorldAxes, true, out);
  if (r.has_rig) {
    const auto& a = r.axes.axis;
    out << fmt::format(
        "rig axes (world): in-plane 1 ({:.3f} {:.3f} {:.3f}), in-plane 2 ({:.3f} {:.3f} {:.3f}), "
        "out-of-plane ({:.3f} {:.3f} {:.3f}):\n",
        a[0].x(), a[0].y(), a[0].z(), a[1].x(), a[1].y(), a[1].z(), a[2].x(), a[2].y(), a[2].z());
    out << header;
    print_axis_rows(r.rig_summary, kRigAxes, false, out);
  } else {
    out << "no --rig: in-plane/out-of-plane axes, stereo angles and the stated centroid u left "
           "out\n";
  }
  print_geometry(r, out);
  if (!r.marks_with_too_few_samples.empty())
    out << fmt::format("marks with fewer than {} samples (not evaluated): {}\n",
                       r.options.min_samples, r.marks_with_too_few_samples.size());
  if (!r.surveyed_marks_not_seen.empty())
    out << fmt::format("surveyed marks never seen: {}\n", r.surveyed_marks_not_seen.size());
}

nlohmann::json noise_floor_json(const eval::NoiseFloorResult& r, const NoiseFloorArgs& args) {
  nlohmann::json doc;
  doc["format"] = "storetrack-eval-noise-floor";
  doc["version"] = 1;
  doc["method"] =
      "Noise-floor test of Ngeljaratan & Moustafa (seed 002): variance error (temporal, spatial) "
      "and bias error per axis of a static record; image-coordinate, stereo-angle and "
      "reconstruction errors";
  doc["inputs"] = {{"marks_csv", args.marks_csv}, {"survey", args.survey}, {"rig", args.rig}};
  doc["bodies"] = r.options.bodies();
  doc["coverage_factor"] = r.options.coverage_factor;
  doc["agreement_level"] = r.options.agreement_level;
  doc["min_samples"] = r.options.min_samples;
  doc["exposures"] = r.exposures;
  doc["duration_s"] = r.duration_s;
  doc["has_rig"] = r.has_rig;
  doc["has_image_coordinates"] = r.has_observations;
  doc["image_coordinates_note"] = r.image_coordinates_note;
  nlohmann::json world = nlohmann::json::object(), rig = nlohmann::json::object();
  for (int a = 0; a < 3; ++a) {
    world[kWorldAxes[a]] = summary_json(r.world_summary[static_cast<size_t>(a)]);
    if (!r.has_rig) continue;
    rig[kRigAxes[a]] = summary_json(r.rig_summary[static_cast<size_t>(a)]);
    const geometry::Vec3& d = r.axes.axis[static_cast<size_t>(a)];
    rig[kRigAxes[a]]["direction_w"] = {d.x(), d.y(), d.z()};
  }
  doc["summary"] = {{"world", world}, {"rig", rig}};
  doc["marks"] = marks_json(r);
  doc["cameras"] = image_json(r);
  const nlohmann::json g = geometry_json(r);
  doc["stereo_angles"] = g["stereo_angles"];
  doc["distances"] = g["distances"];
  doc["max_retriangulation_m"] = r.max_retriangulation_m;
  doc["marks_with_too_few_samples"] = r.marks_with_too_few_samples;
  doc["surveyed_marks_not_seen"] = r.surveyed_marks_not_seen;
  doc["other_body_samples"] = r.other_body_samples;
  doc["excluded_rows"] = r.excluded_rows;
  return doc;
}

int run_noise_floor(const NoiseFloorArgs& args, std::ostream& out, std::ostream& err) {
  eval::NoiseFloorResult result;
  try {
    const survey::RigidBodySurvey reference = survey::read_survey(args.survey);
    std::optional<camera::RigCalibration> rig;
    if (!args.rig.empty()) rig = camera::read_rig_calibration(args.rig);
    const eval::MarksRecording record = eval::read_marks_csv(args.marks_csv);
    result = eval::evaluate_noise_floor(record, reference, args.survey, rig ? &*rig : nullptr,
                                        args.rig, args.options);
  } catch (const eval::EvalInputError& e) {
    err << "storetrack-eval noise-floor: " << e.what() << "\n";
    return 2;
  } catch (const survey::SurveyFileError& e) {
    err << "storetrack-eval noise-floor: " << e.what() << "\n";
    return 2;
  } catch (const camera::CalibrationFileError& e) {
    err << "storetrack-eval noise-floor: " << e.what() << "\n";
    return 2;
  }
  std::ofstream f(args.output, std::ios::trunc);
  f << noise_floor_json(result, args).dump(2) << "\n";
  f.close();
  if (!f) {
    err << "storetrack-eval noise-floor: " << args.output << ": cannot write the result\n";
    return 1;
  }
  print_noise_floor(result, out);
  out << "result: " << args.output << "\n";
  return 0;
}

}  // namespace storetrack::evalapp
