// storetrack-calib register --body-survey (docs/calibration.md, "Register the pylon and the
// store"): the pylon's and the store's poses in S_w through the registered rig, each survey
// checked against its triangulated marks (per-mark chi-square, the fit's chi-square, the scale),
// and with both the store's carriage pose on the pylon, T_p_s, before flight.
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>

#include "command_output.hpp"
#include "register_command.hpp"
#include "storetrack/calib/intrinsic_calibration.hpp"  // CalibrationError
#include "storetrack/camera/calibration_file.hpp"

namespace storetrack::calibapp {
namespace {

struct Body {
  std::string path;
  survey::RigidBodySurvey survey;
  std::vector<calib::MarkSighting> sightings;
  calib::BodyRegistration registration;
};

/// The surveys, and each observation row given to the body whose survey has its mark id; a row
/// of no survey, or a mark id in two surveys, is refused naming the files.
std::vector<Body> read_bodies(const RegisterArgs& args) {
  std::vector<Body> bodies;
  std::map<int, std::string> owner;  // mark id -> survey file
  for (const std::string& path : args.body_surveys) {
    Body b{path, survey::read_survey(path), {}, {}};
    for (const auto& m : b.survey.marks)
      if (const auto [at, fresh] = owner.emplace(m.id, path); !fresh)
        throw calib::CalibrationError(path + ": marks: mark " + std::to_string(m.id) +
                                      " is also in " + at->second +
                                      " (mark ids must be unique over the surveys)");
    bodies.push_back(std::move(b));
  }
  for (const calib::MarkSighting& s : read_sightings(args)) {
    const auto at = owner.find(s.mark_id);
    if (at == owner.end())
      throw calib::CalibrationError(args.observations + ": point_id: mark " +
                                    std::to_string(s.mark_id) + " (camera " +
                                    std::to_string(s.camera) + ") is in none of the surveys");
    for (Body& b : bodies)
      if (b.path == at->second) b.sightings.push_back(s);
  }
  return bodies;
}

std::string scale_text(double scale, double sigma) {
  char text[160];
  std::snprintf(text, sizeof text, "%+.0f +/- %.0f ppm (z = %+.2f)", scale * 1e6, sigma * 1e6,
                scale / sigma);
  return text;
}

void print_body(const Body& b, std::ostream& out) {
  const calib::BodyRegistration& r = b.registration;
  const std::string pose = "T_w_" + std::string(1, r.frame) + " (" + r.body + ")";
  out << r.body << " (" << b.path << "): " << r.marks.size() << " marks, " << r.skipped.size()
      << " not usable\n";
  print_pose(pose.c_str(), r.T_w_b, r.cov_T_w_b, out);
  out << "  standard uncertainty per axis (rms rotation, translation): "
      << sigmas_by_source(r.cov_T_w_b, r.cov_T_w_b_centroid, r.cov_T_w_b_calibration,
                          r.cov_T_w_b_survey)
      << "\n";
  out << "  mark  residual p_w - T_w_b q_b [mm]   survey sigma [mm]  chi2/dof      p\n";
  for (const auto& m : r.marks) {
    char line[200];
    std::snprintf(line, sizeof line, "  %4d %8.3f %8.3f %8.3f %12.3f %10.2f/%d %8.2g%s\n",
                  m.mark_id, m.residual_w.x() * 1e3, m.residual_w.y() * 1e3, m.residual_w.z() * 1e3,
                  m.survey_sigma_m * 1e3, m.chi2, m.dof, m.p_value,
                  !m.used ? "  OUTLIER, rejected" : (m.outlier ? "  OUTLIER, kept" : ""));
    out << line;
  }
  out << "  survey check: fit chi2 " << r.chi2 << " for " << r.dof << " dof (p = " << r.p_value
      << "); scale of the triangulated marks against the survey "
      << scale_text(r.scale_error, r.scale_error_sigma) << "\n";
}

nlohmann::json body_json(const Body& b) {
  const calib::BodyRegistration& r = b.registration;
  return {
      {"name", r.body},
      {"frame", std::string(1, r.frame)},
      {"survey", b.path},
      {"T_w_b", transform_json(r.T_w_b)},
      {"T_w_b_covariance", covariance_by_source_json(r.cov_T_w_b, r.cov_T_w_b_centroid,
                                                     r.cov_T_w_b_calibration, r.cov_T_w_b_survey)},
      {"chi2", r.chi2},
      {"dof", r.dof},
      {"p_value", r.p_value},
      {"scale_error", r.scale_error},
      {"scale_error_sigma", r.scale_error_sigma},
      {"marks", marks_json(r.marks, 'w', &calib::BodyMarkRegistration::p_w,
                           &calib::BodyMarkRegistration::residual_w)},
      {"skipped", skipped_json(r.skipped)}};
}

const Body* find_frame(const std::vector<Body>& bodies, char frame) {
  for (const Body& b : bodies)
    if (b.registration.frame == frame) return &b;
  return nullptr;
}

}  // namespace

int run_register_bodies(const RegisterArgs& args, std::ostream& out, std::ostream& err) {
  std::vector<Body> bodies;
  Eigen::MatrixXd covariance;
  std::string covariance_source;
  try {
    const camera::RigCalibration rig = camera::read_rig_calibration(args.rig);
    covariance = input_calibration_covariance(rig, covariance_source);
    bodies = read_bodies(args);
    for (Body& b : bodies) {
      calib::RegistrationOptions options;
      options.rig_origin = args.rig;
      options.survey_origin = b.path;
      options.observations_origin = args.observations;
      options.outlier_false_alarm = args.outlier_false_alarm;
      options.reject_outliers = !args.keep_outliers;
      b.registration = calib::register_body(rig, covariance, b.survey, b.sightings, options);
    }
  } catch (const std::exception& e) {  // file errors, CalibrationError
    err << "error: " << e.what() << "\n";
    return 2;
  }
  out << "register bodies through " << args.rig << "; calibration covariance: " << covariance_source
      << "\n";
  nlohmann::json doc = {{"format", "storetrack-body-registration"},
                        {"version", 1},
                        {"produced_by", "storetrack-calib register --body-survey"},
                        {"inputs", {{"rig", args.rig}, {"observations", args.observations}}},
                        {"bodies", nlohmann::json::array()}};
  for (const Body& b : bodies) {
    for (const auto& s : b.registration.skipped)
      err << "not used: " << s.reason << "\n";
    print_body(b, out);
    doc["bodies"].push_back(body_json(b));
  }
  const Body* pylon = find_frame(bodies, 'p');
  const Body* store = find_frame(bodies, 's');
  if (pylon != nullptr && store != nullptr) {
    const calib::RelativePose ps =
        calib::relative_pose(pylon->registration, store->registration, covariance);
    print_pose("T_p_s (store on the pylon, carriage pose)", ps.T_a_b, ps.cov_T_a_b, out);
    doc["T_p_s"] = transform_json(ps.T_a_b);
    doc["T_p_s_covariance"] = matrix_json(ps.cov_T_a_b);
  }
  return write_outputs(args.output, out, err, [&] { write_text(args.output, doc.dump(2) + "\n"); });
}

}  // namespace storetrack::calibapp
