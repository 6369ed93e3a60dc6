#include "pendulum_command.hpp"

#include <fmt/format.h>

#include <cmath>
#include <fstream>

#include "storetrack/camera/calibration_file.hpp"

namespace storetrack::evalapp {
namespace {

constexpr const char* kAxes[3] = {"x", "y", "z"};

nlohmann::json vec(const geometry::Vec3& v) {
  return {v.x(), v.y(), v.z()};
}

nlohmann::json axis_json(const eval::DynamicAxis& a) {
  return {{"mean_m", a.mean_m},
          {"sd_m", a.sd_m},
          {"u_reference_m", a.u_reference_m},
          {"u_stated_m", a.u_stated_m}};
}

nlohmann::json axes_json(const std::array<eval::DynamicAxis, 3>& a) {
  nlohmann::json j = nlohmann::json::object();
  for (size_t k = 0; k < 3; ++k)
    j[kAxes[k]] = axis_json(a[k]);
  return j;
}

nlohmann::json bins_json(const std::vector<eval::DynamicBin>& bins) {
  nlohmann::json j = nlohmann::json::array();
  for (const eval::DynamicBin& b : bins)
    j.push_back({{"low", b.low}, {"high", b.high}, {"samples", b.samples}, {"rms_m", b.rms_m}});
  return j;
}

nlohmann::json nullable(double v) {
  return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
}

const char* covariance_description(eval::CovarianceScale scale) {
  switch (scale) {
    case eval::CovarianceScale::kObserved:
      return "observed: sandwich from the residuals per exposure";
    case eval::CovarianceScale::kResidual:
      return "scaled by the residual variance";
    case eval::CovarianceScale::kStated:
      return "of the stated covariance";
  }
  return "";
}

void print_parameters(const eval::PendulumResult& r, std::ostream& out) {
  out << fmt::format(
      "model m l2^2 theta'' + beta theta' + m g l1 sin(theta) = 0, g = {:.7f} m/s^2; parameters "
      "+- 1 sigma (covariance {}; reduced chi^2 {:.4f}, {} residuals, {} parameters)\n",
      r.options.g_m_s2, covariance_description(r.options.covariance_scale), r.reduced_chi_square,
      r.residuals, r.parameters);
  out << fmt::format("  L = l2^2/l1          {:.6f} +- {:.6f} m (omega0 {:.5f} rad/s)\n",
                     r.equivalent_length_m, r.equivalent_length_sigma_m, r.omega0_rad_s);
  out << fmt::format("  beta/(m l2^2)        {:.6f} +- {:.6f} 1/s\n", r.damping_per_inertia_1_s,
                     r.damping_per_inertia_sigma_1_s);
  if (r.l2_m)
    out << fmt::format("  l2 (l1 given)        {:.6f} +- {:.6f} m; beta/m {:.3e} +- {:.1e} m^2/s\n",
                       *r.l2_m, *r.l2_sigma_m, *r.beta_per_mass_m2_s, *r.beta_per_mass_sigma_m2_s);
  out << fmt::format(
      "  pivot (w)            {:.5f} {:.5f} {:.5f} m +- {:.4f} {:.4f} {:.4f} mm\n", r.pivot_w.x(),
      r.pivot_w.y(), r.pivot_w.z(), 1e3 * std::sqrt(r.pivot_covariance(0, 0)),
      1e3 * std::sqrt(r.pivot_covariance(1, 1)), 1e3 * std::sqrt(r.pivot_covariance(2, 2)));
  out << fmt::format("  plane normal (w)     {:.6f} {:.6f} {:.6f} +- {:.4f} mrad\n", r.normal_w.x(),
                     r.normal_w.y(), r.normal_w.z(), 1e3 * r.normal_sigma_rad);
  for (const eval::PendulumRunEstimate& e : r.runs)
    out << fmt::format(
        "  run {}: {} theta0 {:.4f} +- {:.4f} deg, release {:.6f} +- {:.6f} s after its first "
        "exposure ({} of {} exposures after it), RMS error {:.3f} mm\n",
        e.path, e.clockwise ? "clockwise" : "counter-clockwise", e.theta0_rad * 180 / M_PI,
        e.theta0_sigma_rad * 180 / M_PI, e.release_s, e.release_sigma_s, e.exposures_after_release,
        e.exposures, 1e3 * e.rms_residual_m);
  for (const eval::PendulumMarkEstimate& m : r.marks)
    out << fmt::format(
        "  mark {:>4}: radius {:.5f} m +- {:.4f} mm, angle {:.4f} +- {:.4f} deg, offset {:.4f} +- "
        "{:.4f} mm\n",
        m.mark_id, m.radius_m, 1e3 * m.radius_sigma_m, m.angle_rad * 180 / M_PI,
        m.angle_sigma_rad * 180 / M_PI, 1e3 * m.offset_m, 1e3 * m.offset_sigma_m);
}

void print_bins(const char* title, const char* unit, double scale,
                const std::vector<eval::DynamicBin>& bins, std::ostream& out) {
  if (bins.empty()) return;
  out << fmt::format("dynamic error (RMS) by {} [mm]:\n  {:>17}  samples      x      y      z\n",
                     title, unit);
  for (const eval::DynamicBin& b : bins)
    out << fmt::format("  {:>7.3f} .. {:<7.3f}  {:>7}  {:>5.3f}  {:>5.3f}  {:>5.3f}\n",
                       scale * b.low, scale * b.high, b.samples, 1e3 * b.rms_m[0], 1e3 * b.rms_m[1],
                       1e3 * b.rms_m[2]);
}

void print_summary(const eval::PendulumResult& r, std::ostream& out) {
  out << fmt::format(
      "storetrack-eval pendulum: {} runs ({} clockwise, {} counter-clockwise samples), {} marks "
      "of body '{}'\n",
      r.runs.size(), r.samples_clockwise, r.samples_counter_clockwise, r.marks.size(),
      r.options.body);
  print_parameters(r, out);
  out << "per axis (SisTrO dynamic table) [mm], 1 sigma (k = 1; U = 2 sigma for k = 2):\n"
         "  axis  dynamic error (mean +- sd)   model error (cw - ccw)   u_reference  "
         "u_stated (RMS)\n";
  for (size_t k = 0; k < 3; ++k) {
    const eval::DynamicAxis& a = r.dynamic[k];
    const std::string model = std::isfinite(r.model_error_m[k])
                                  ? fmt::format("{:>8.3f} +- {:<7.3f}", 1e3 * r.model_error_m[k],
                                                1e3 * r.model_error_u_m[k])
                                  : std::string("   (one direction only)");
    out << fmt::format("  {:>4}  {:>10.3f} +- {:<10.3f}     {:<23}  {:>11.4f}  {:>14.3f}\n",
                       kAxes[k], 1e3 * a.mean_m, 1e3 * a.sd_m, model, 1e3 * a.u_reference_m,
                       1e3 * a.u_stated_m);
  }
  print_bins("distance from the optical axis", "distance [m]", 1, r.by_axis_distance, out);
  print_bins("mark speed", "speed [m/s]", 1, r.by_speed, out);
  if (r.other_body_samples > 0 || r.excluded_rows > 0)
    out << fmt::format("left out: {} samples of other bodies, {} rows the host excluded\n",
                       r.other_body_samples, r.excluded_rows);
}

}  // namespace

void add_pendulum_command(cli::Command& app, PendulumArgs& a) {
  cli::Command& sub = app.subcommand(
      "pendulum", "SisTrO dynamic calibration: identify the pendulum, dynamic error per axis");
  sub.option("marks_csv", a.marks_csv, "The host's --marks-csv, one file per run (release)")
      .required()
      .existing_file();
  sub.option("--body", a.body, "The pendulum's marks are of this body (the host's store: s)")
      .one_of({"p", "s", "?"})
      .show_default();
  sub.option("--g", a.options.g_m_s2, "Local gravity [m/s^2]").positive().show_default();
  sub.option("--down-w", a.down_w, "Gravity direction in the world frame (x,y,z)")
      .delimiter(',')
      .expected(3);
  sub.option("--l1", a.l1_m, "Pivot to centre of mass [m], if known (gives l2 and beta/m)")
      .non_negative();
  sub.option("--l1-sigma", a.l1_sigma_m, "Standard uncertainty of --l1 [m]").non_negative();
  sub.option("--covariance", a.covariance,
             "Parameter covariance: observed (sandwich, residuals per exposure), residual "
             "(s^2 (J^T W J)^-1, s^2 = chi^2/(n-p)) or stated ((J^T W J)^-1, the host's u)")
      .one_of({"observed", "residual", "stated"})
      .show_default();
  sub.option("--calibration", a.calibration,
             "Rig calibration: bins the error by distance from the reference camera's axis")
      .existing_file();
  sub.option("--axis-camera", a.axis_camera, "Camera id of the reference camera (default: first)");
  sub.option("--min-exposures-after-release", a.options.min_exposures_after_release,
             "A run with fewer exposures after its release is refused")
      .range(5, 1000000)
      .show_default();
  sub.option("-o,--output", a.output, "Result JSON to write").required();
}

void finish_pendulum_args(PendulumArgs& a) {
  a.options.body = a.body[0];
  if (a.l1_m > 0) {
    a.options.l1_m = a.l1_m;
    a.options.l1_sigma_m = a.l1_sigma_m;
  }
  a.options.covariance_scale = a.covariance == "stated"     ? eval::CovarianceScale::kStated
                               : a.covariance == "residual" ? eval::CovarianceScale::kResidual
                                                            : eval::CovarianceScale::kObserved;
  a.options.down_w = geometry::Vec3(a.down_w[0], a.down_w[1], a.down_w[2]);
}

nlohmann::json pendulum_json(const eval::PendulumResult& r, const PendulumArgs& args) {
  nlohmann::json doc;
  doc["format"] = "storetrack-eval-pendulum";
  doc["version"] = 1;
  doc["method"] =
      "SisTrO pendulum dynamic calibration: m l2^2 theta'' + beta theta' + m g l1 sin(theta) = 0 "
      "identified by non-linear least squares (Ceres) from the measured 3-D mark trajectories";
  doc["inputs"] = {{"marks_csv", args.marks_csv}, {"calibration", args.calibration}};
  doc["body"] = std::string(1, r.options.body);
  doc["g_m_s2"] = r.options.g_m_s2;
  doc["down_w"] = vec(r.options.down_w);
  doc["covariance_scale"] = args.covariance;
  doc["fit"] = {{"residuals", r.residuals},
                {"parameters", r.parameters},
                {"reduced_chi_square", r.reduced_chi_square},
                {"iterations", r.solver_iterations}};
  nlohmann::json p = {
      {"equivalent_length_m", r.equivalent_length_m},
      {"equivalent_length_sigma_m", r.equivalent_length_sigma_m},
      {"damping_per_inertia_1_s", r.damping_per_inertia_1_s},
      {"damping_per_inertia_sigma_1_s", r.damping_per_inertia_sigma_1_s},
      {"omega0_rad_s", r.omega0_rad_s},
      {"pivot_w_m", vec(r.pivot_w)},
      {"pivot_sigma_m", vec(r.pivot_covariance.diagonal().cwiseMax(0.0).cwiseSqrt())},
      {"normal_w", vec(r.normal_w)},
      {"normal_sigma_rad", r.normal_sigma_rad}};
  if (r.l2_m) {
    p["l1_m"] = *r.options.l1_m;
    p["l1_sigma_m"] = r.options.l1_sigma_m;
    p["l2_m"] = *r.l2_m;
    p["l2_sigma_m"] = *r.l2_sigma_m;
    p["beta_per_mass_m2_s"] = *r.beta_per_mass_m2_s;
    p["beta_per_mass_sigma_m2_s"] = *r.beta_per_mass_sigma_m2_s;
  }
  doc["parameters"] = p;
  doc["other_body_samples"] = r.other_body_samples;
  doc["excluded_rows"] = r.excluded_rows;
  for (const eval::PendulumRunEstimate& e : r.runs)
    doc["runs"].push_back({{"marks_csv", e.path},
                           {"direction", e.clockwise ? "clockwise" : "counter-clockwise"},
                           {"theta0_rad", e.theta0_rad},
                           {"theta0_sigma_rad", e.theta0_sigma_rad},
                           {"release_s", e.release_s},
                           {"release_sigma_s", e.release_sigma_s},
                           {"release_tai_ns", e.release_tai_ns},
                           {"exposures", e.exposures},
                           {"exposures_after_release", e.exposures_after_release},
                           {"rms_error_m", e.rms_residual_m}});
  for (const eval::PendulumMarkEstimate& m : r.marks)
    doc["marks"].push_back({{"mark_id", m.mark_id},
                            {"radius_m", m.radius_m},
                            {"radius_sigma_m", m.radius_sigma_m},
                            {"angle_rad", m.angle_rad},
                            {"angle_sigma_rad", m.angle_sigma_rad},
                            {"offset_m", m.offset_m},
                            {"offset_sigma_m", m.offset_sigma_m}});
  nlohmann::json model = nlohmann::json::object();
  for (size_t k = 0; k < 3; ++k)
    model[kAxes[k]] = {{"mean_m", nullable(r.model_error_m[k])},
                       {"sd_m", nullable(r.model_error_u_m[k])}};
  doc["dynamic"] = {{"all", axes_json(r.dynamic)},
                    {"clockwise", axes_json(r.dynamic_clockwise)},
                    {"counter_clockwise", axes_json(r.dynamic_counter_clockwise)},
                    {"samples_clockwise", r.samples_clockwise},
                    {"samples_counter_clockwise", r.samples_counter_clockwise},
                    {"model_error", model},
                    {"by_axis_distance_m", bins_json(r.by_axis_distance)},
                    {"by_speed_m_s", bins_json(r.by_speed)}};
  return doc;
}

int run_pendulum(PendulumArgs args, std::ostream& out, std::ostream& err) {
  eval::PendulumResult result;
  try {
    if (!args.calibration.empty()) {
      const camera::RigCalibration rig = camera::read_rig_calibration(args.calibration);
      const camera::CalibratedCamera* cam =
          args.axis_camera >= 0 ? rig.find(args.axis_camera)
                                : (rig.cameras.empty() ? nullptr : &rig.cameras.front());
      if (!cam)
        throw eval::EvalInputError(args.calibration + ": camera " +
                                   std::to_string(args.axis_camera) + ": not in the rig");
      args.options.T_w_camera = cam->T_c_w.inverse();
    }
    std::vector<eval::MarksRecording> recordings;
    for (const std::string& path : args.marks_csv)
      recordings.push_back(eval::read_marks_csv(path));
    result = eval::identify_pendulum(eval::pendulum_runs(recordings, args.options), args.options);
  } catch (const eval::EvalInputError& e) {
    err << "storetrack-eval pendulum: " << e.what() << "\n";
    return 2;
  } catch (const camera::CalibrationFileError& e) {
    err << "storetrack-eval pendulum: " << e.what() << "\n";
    return 2;
  }
  std::ofstream f(args.output, std::ios::trunc);
  f << pendulum_json(result, args).dump(2) << "\n";
  f.close();
  if (!f) {
    err << "storetrack-eval pendulum: " << args.output << ": cannot write the result\n";
    return 1;
  }
  print_summary(result, out);
  out << "result: " << args.output << "\n";
  return 0;
}

}  // namespace storetrack::evalapp
