#include "register_command.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "command_output.hpp"
#include "storetrack/calib/intrinsic_calibration.hpp"  // CalibrationError
#include "storetrack/calib/observations.hpp"
#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/json/text_file.hpp"

namespace storetrack::calibapp {
namespace {

using geometry::Mat6;
using geometry::Transform;
using geometry::Vec3;

std::string fixed(double v, int decimals) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

std::string text_of(const std::string& path) {
  try {
    return jsonfile::read_text_file(path);
  } catch (const jsonfile::FileReadError& e) {
    throw camera::CalibrationFileError(e.what());
  }
}

void print_summary(const calib::RegistrationResult& r, const std::string& covariance_source,
                   const RegisterArgs& args, std::ostream& out) {
  const auto used =
      std::count_if(r.marks.begin(), r.marks.end(), [](const auto& m) { return m.used; });
  out << "register: " << used << " marks used, " << r.marks.size() - static_cast<size_t>(used)
      << " rejected as outliers, " << r.skipped.size()
      << " not usable; calibration covariance: " << covariance_source << "\n";
  print_pose("T_w_r (S_r -> S_w)", r.T_w_r, r.cov_T_w_r, out);
  out << "standard uncertainty of T_r_w per axis (rms rotation, translation): "
      << sigmas_by_source(r.cov_T_r_w, r.cov_T_r_w_centroid, r.cov_T_r_w_calibration,
                          r.cov_T_r_w_survey)
      << "\n";
  out << "mark cameras   residual p_r - T_r_w q_w [mm]      |r| [mm] survey sigma [mm] "
         "chi2/dof    p\n";
  for (const auto& m : r.marks) {
    std::string cams;
    for (int c : m.cameras) {
      if (!cams.empty()) cams += ',';
      cams += std::to_string(c);
    }
    char line[256];
    std::snprintf(
        line, sizeof line, "%4d %-8s %8.3f %8.3f %8.3f   %8.3f %10.3f %10.2f/%d %8.2g%s\n",
        m.mark_id, cams.c_str(), m.residual_r.x() * 1e3, m.residual_r.y() * 1e3,
        m.residual_r.z() * 1e3, m.residual_r.norm() * 1e3, m.survey_sigma_m * 1e3, m.chi2, m.dof,
        m.p_value, !m.used ? "  OUTLIER, rejected" : (m.outlier ? "  OUTLIER, kept" : ""));
    out << line;
  }
  out << "fit: chi2 " << fixed(r.chi2, 2) << " for " << r.dof << " dof (p = " << r.p_value << "), "
      << r.iterations << " Gauss-Newton iterations\n";
  out << "scale of the triangulated marks against the survey: " << fixed(r.scale_error * 1e6, 0)
      << " +/- " << fixed(r.scale_error_sigma * 1e6, 0) << " ppm\n";
  std::string outliers;
  for (const auto& m : r.marks)
    if (m.outlier) {
      if (!outliers.empty()) outliers += ", ";
      outliers += std::to_string(m.mark_id);
    }
  out << "outliers (p < " << args.outlier_false_alarm << " / " << used
      << "): " << (outliers.empty() ? "none" : outliers) << "\n";
  for (const auto& c : r.registered.cameras)
    print_pose(("camera " + std::to_string(c.camera_id) + " T_c_w").c_str(), c.T_c_w,
               c.extrinsic_covariance, out);
}

}  // namespace

nlohmann::json matrix_json(const Eigen::MatrixXd& m) {
  nlohmann::json rows = nlohmann::json::array();
  for (Eigen::Index i = 0; i < m.rows(); ++i) {
    nlohmann::json row = nlohmann::json::array();
    for (Eigen::Index j = 0; j < m.cols(); ++j)
      row.push_back(m(i, j));
    rows.push_back(row);
  }
  return rows;
}

nlohmann::json transform_json(const Transform& T) {
  const Vec3 r = geometry::rotvec_from_rotation(T.linear());
  const Vec3 t = T.translation();
  return {{"rotation_vector_rad", {r.x(), r.y(), r.z()}}, {"translation_m", {t.x(), t.y(), t.z()}}};
}

/// Marks' sightings from the observation CSV: point_id is the survey mark id, the board
/// columns are unused and must be 0 (a board file given by mistake is refused).
std::vector<calib::MarkSighting> read_sightings(const RegisterArgs& args) {
  const calib::ObservationSet set = calib::read_observations_csv(args.observations);
  std::vector<calib::MarkSighting> sightings;
  for (const calib::Observation& o : set.observations) {
    if (o.p_board != Eigen::Vector3d::Zero())
      throw calib::ObservationFileError(
          args.observations +
          ": board_x_m/board_y_m/board_z_m: must be 0 in a marks file "
          "(camera " +
          std::to_string(o.camera) + ", point_id " + std::to_string(o.point_id) +
          "): is this a board observation file?");
    sightings.push_back({o.camera, o.point_id, o.pixel, o.sigma_px.value_or(args.sigma_px)});
  }
  return sightings;
}

/// "rotation [deg] a b c +/- ..., translation [mm] ..." of a pose and its covariance.
void print_pose(const char* name, const Transform& T, const Mat6& C, std::ostream& out) {
  const Vec3 r = geometry::rotvec_from_rotation(T.linear()) * 180 / M_PI;
  const Vec3 t = T.translation() * 1000;
  const auto sd = [&](int i) { return std::sqrt(std::max(0.0, C(i, i))); };
  out << name << " rotation vector [deg]:";
  for (int i = 0; i < 3; ++i)
    out << ' ' << fixed(r[i], 5) << " +/- " << fixed(sd(i) * 180 / M_PI, 5);
  out << "\n" << name << " translation [mm]:";
  for (int i = 0; i < 3; ++i)
    out << ' ' << fixed(t[i], 3) << " +/- " << fixed(sd(3 + i) * 1000, 3);
  out << "\n";
}

/// RMS over the 3 axes of the rotation [mdeg] and translation [mm] standard uncertainties.
std::string rms_sigmas(const Mat6& C) {
  const double rot = std::sqrt(std::max(0.0, C.topLeftCorner<3, 3>().trace() / 3));
  const double trans = std::sqrt(std::max(0.0, C.bottomRightCorner<3, 3>().trace() / 3));
  return fixed(rot * 180 / M_PI * 1000, 2) + " mdeg, " + fixed(trans * 1000, 3) + " mm";
}

std::string sigmas_by_source(const Mat6& total, const Mat6& centroid, const Mat6& calibration,
                             const Mat6& survey) {
  return "total " + rms_sigmas(total) + "; centroid " + rms_sigmas(centroid) + ", calibration " +
         rms_sigmas(calibration) + ", survey " + rms_sigmas(survey);
}

nlohmann::json covariance_by_source_json(const Mat6& total, const Mat6& centroid,
                                         const Mat6& calibration, const Mat6& survey) {
  return {{"total", matrix_json(total)},
          {"centroid", matrix_json(centroid)},
          {"calibration", matrix_json(calibration)},
          {"survey", matrix_json(survey)}};
}

nlohmann::json skipped_json(const std::vector<calib::SkippedMark>& skipped) {
  nlohmann::json rows = nlohmann::json::array();
  for (const auto& s : skipped)
    rows.push_back({{"id", s.mark_id}, {"reason", s.reason}});
  return rows;
}

void add_register(cli::Command& app, RegisterArgs& a) {
  cli::Command& sub = app.subcommand(
      "register", "S_r -> S_w from total-station marks: every camera's T_c_w with covariance");
  sub.option("rig", a.rig, "Rig calibration JSON of the rig step (world = S_r)")
      .required()
      .existing_file();
  sub.option("--survey", a.survey, "Survey JSON of the marks in frame w").existing_file();
  sub.option("--body-survey", a.body_surveys,
             "Instead of --survey: a pylon ('p') or store ('s') survey, registered through a "
             "registered rig (repeatable; both: also T_p_s)")
      .existing_file();
  sub.option("--observations", a.observations, "Observation CSV, point_id = survey mark id")
      .required()
      .existing_file();
  sub.option("--sigma-px", a.sigma_px, "Centroid sigma [px] for rows without sigma_px").positive();
  sub.option("--outlier-false-alarm", a.outlier_false_alarm,
             "Probability of naming any mark of a clean set an outlier")
      .range(1e-9, 0.5);
  sub.flag("--keep-outliers", a.keep_outliers, "Name failing marks but keep them in the fit");
  sub.option("-o,--output", a.output, "Registered rig calibration JSON to write").required();
  sub.option("--residuals", a.residuals_csv, "Per-mark residual CSV to write");
}

Eigen::MatrixXd input_calibration_covariance(const camera::RigCalibration& rig,
                                             std::string& source) {
  if (rig.joint_covariance.size() != 0) {
    source = "joint (the file's joint_covariance, cross-camera terms included)";
    return rig.joint_covariance;
  }
  source = "per-camera blocks (no joint covariance in the file: cross-camera terms taken as 0)";
  return rig.full_joint_covariance();
}

std::string registered_calibration_json(const calib::RegistrationResult& r,
                                        const std::string& rig_json_text,
                                        const RegisterArgs& args) {
  nlohmann::json doc = nlohmann::json::parse(camera::format_rig_calibration(r.registered));
  const nlohmann::json input = nlohmann::json::parse(rig_json_text);
  for (size_t i = 0; i < r.registered.cameras.size(); ++i)  // keep the rig step's fit summary
    if (input["cameras"][i].contains("comment"))
      doc["cameras"][i]["comment"] = input["cameras"][i]["comment"];
  doc["comment"] = {
      {"produced_by", "storetrack-calib register"},
      {"inputs", {{"rig", args.rig}, {"survey", args.survey}, {"observations", args.observations}}},
      {"extrinsics",
       "T_c_w = T_c_r T_r_w: world = the surveyed aircraft frame S_w. Each camera's extrinsic "
       "covariance includes the registration's; the registration error common to all cameras "
       "(and its correlation with the intrinsics) is in the file's joint_covariance"},
      {"T_w_r", transform_json(r.T_w_r)},
      {"T_w_r_covariance", matrix_json(r.cov_T_w_r)},
      {"T_r_w", transform_json(r.T_r_w)},
      {"T_r_w_covariance", covariance_by_source_json(r.cov_T_r_w, r.cov_T_r_w_centroid,
                                                     r.cov_T_r_w_calibration, r.cov_T_r_w_survey)},
      {"chi2", r.chi2},
      {"dof", r.dof},
      {"p_value", r.p_value},
      {"scale_error", r.scale_error},
      {"scale_error_sigma", r.scale_error_sigma},
      {"outlier_false_alarm", args.outlier_false_alarm},
      {"marks", marks_json(r.marks, 'r', &calib::MarkRegistration::p_r,
                           &calib::MarkRegistration::residual_r)},
      {"skipped", skipped_json(r.skipped)}};
  return doc.dump(2) + "\n";
}

int run_register(const RegisterArgs& args, std::ostream& out, std::ostream& err) {
  if (args.survey.empty() == args.body_surveys.empty()) {
    err << "error: give either --survey (frame w: register the rig) or --body-survey (pylon, "
           "store: register bodies through a registered rig)\n";
    return 2;
  }
  if (!args.body_surveys.empty()) return run_register_bodies(args, out, err);
  calib::RegistrationResult result;
  std::string rig_text, covariance_source;
  try {
    rig_text = text_of(args.rig);
    const camera::RigCalibration rig = camera::parse_rig_calibration(rig_text, args.rig);
    const Eigen::MatrixXd covariance = input_calibration_covariance(rig, covariance_source);
    const survey::RigidBodySurvey survey = survey::read_survey(args.survey);
    calib::RegistrationOptions options;
    options.rig_origin = args.rig;
    options.survey_origin = args.survey;
    options.observations_origin = args.observations;
    options.outlier_false_alarm = args.outlier_false_alarm;
    options.reject_outliers = !args.keep_outliers;
    result = calib::register_rig(rig, covariance, survey, read_sightings(args), options);
  } catch (const std::exception& e) {  // file errors, CalibrationError
    err << "error: " << e.what() << "\n";
    return 2;
  }
  for (const auto& s : result.skipped)
    err << "not used: " << s.reason << "\n";
  print_summary(result, covariance_source, args, out);
  return write_outputs(args.output, out, err, [&] {
    write_text(args.output, registered_calibration_json(result, rig_text, args));
    if (!args.residuals_csv.empty()) {
      std::ostringstream rows;
      rows << "mark_id,residual_x_m,residual_y_m,residual_z_m,chi2,dof,p_value,used,outlier\n";
      for (const auto& m : result.marks)
        rows << m.mark_id << ',' << m.residual_r.x() << ',' << m.residual_r.y() << ','
             << m.residual_r.z() << ',' << m.chi2 << ',' << m.dof << ',' << m.p_value << ','
             << (m.used ? 1 : 0) << ',' << (m.outlier ? 1 : 0) << '\n';
      write_text(args.residuals_csv, rows.str());
    }
  });
}

}  // namespace storetrack::calibapp
