// storetrack-calib register: S_r -> S_w from total-station marks (docs/calibration.md,
// "Register"): reads the rig step's calibration, the world-frame survey and the marks' image
// observations, writes the registered rig calibration file. With --body-survey instead of
// --survey (pylon, store): the bodies' poses in S_w through the registered rig, their surveys
// checked against the triangulated marks, and the carriage pose T_p_s (body_registration.cpp).
#pragma once

#include <ostream>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "storetrack/calib/world_registration.hpp"
#include "storetrack/cli/command_line.hpp"

namespace storetrack::calibapp {

struct RegisterArgs {
  std::string rig;     ///< rig calibration file (the `rig` step's, world = S_r)
  std::string survey;  ///< storetrack-survey JSON, frame "w"
  /// Instead of `survey`: body surveys ('p' pylon, 's' store) registered through a registered rig.
  std::vector<std::string> body_surveys;
  std::string observations;  ///< observation CSV, point_id = survey mark id
  double sigma_px = 0;       ///< centroid sigma for rows without sigma_px (0: none given)
  double outlier_false_alarm = 0.01;
  bool keep_outliers = false;  ///< name failing marks but keep them in the fit
  std::string output;
  std::string residuals_csv;
};

void add_register(cli::Command& app, RegisterArgs& args);
int run_register(const RegisterArgs& args, std::ostream& out, std::ostream& err);

/// --body-survey: every body's T_w_b, its survey's check, and T_p_s with pylon and store.
int run_register_bodies(const RegisterArgs& args, std::ostream& out, std::ostream& err);

/// The observation CSV's rows as sightings (point_id = mark id; board columns must be 0).
std::vector<calib::MarkSighting> read_sightings(const RegisterArgs& args);

/// Console summary helpers shared by the rig's and the bodies' registration.
void print_pose(const char* name, const geometry::Transform& T, const geometry::Mat6& C,
                std::ostream& out);
std::string rms_sigmas(const geometry::Mat6& C);
nlohmann::json matrix_json(const Eigen::MatrixXd& m);
nlohmann::json transform_json(const geometry::Transform& T);

/// "total A; centroid B, calibration C, survey D": rms_sigmas of a pose covariance by source.
std::string sigmas_by_source(const geometry::Mat6& total, const geometry::Mat6& centroid,
                             const geometry::Mat6& calibration, const geometry::Mat6& survey);
/// {"total", "centroid", "calibration", "survey"}: a pose covariance by source.
nlohmann::json covariance_by_source_json(const geometry::Mat6& total,
                                         const geometry::Mat6& centroid,
                                         const geometry::Mat6& calibration,
                                         const geometry::Mat6& survey);

/// The "marks" table of a registration (the rig's, MarkRegistration, or a body's,
/// BodyMarkRegistration): each mark's triangulated position `p` and residual `residual` in the
/// frame `frame` (keys "p_<frame>_m", "residual_<frame>_m"), its test, used, outlier.
template <class Mark>
nlohmann::json marks_json(const std::vector<Mark>& marks, char frame, geometry::Vec3 Mark::*p,
                          geometry::Vec3 Mark::*residual) {
  const std::string f(1, frame);
  nlohmann::json rows = nlohmann::json::array();
  for (const Mark& m : marks) {
    const geometry::Vec3& at = m.*p;
    const geometry::Vec3& r = m.*residual;
    rows.push_back({{"id", m.mark_id},
                    {"cameras", m.cameras},
                    {"p_" + f + "_m", {at.x(), at.y(), at.z()}},
                    {"residual_" + f + "_m", {r.x(), r.y(), r.z()}},
                    {"chi2", m.chi2},
                    {"dof", m.dof},
                    {"p_value", m.p_value},
                    {"used", m.used},
                    {"outlier", m.outlier}});
  }
  return rows;
}

/// The "skipped" table of a registration: each unusable mark and why.
nlohmann::json skipped_json(const std::vector<calib::SkippedMark>& skipped);

/// The rig file's joint covariance (file version 2, written by `rig`), else its per-camera
/// blocks (version 1: cross terms 0). `source` says which.
Eigen::MatrixXd input_calibration_covariance(const camera::RigCalibration& rig,
                                             std::string& source);

/// The registered calibration file (version 1 blocks) with the registration in its comment.
std::string registered_calibration_json(const calib::RegistrationResult& result,
                                        const std::string& rig_json_text, const RegisterArgs& args);

}  // namespace storetrack::calibapp
