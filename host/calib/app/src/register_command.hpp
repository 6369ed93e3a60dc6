// storetrack-calib register: S_r -> S_w from total-station marks (docs/calibration.md,
// "Register"): reads the rig step's calibration, the world-frame survey and the marks' image
// observations, writes the registered rig calibration file.
#pragma once

#include <ostream>
#include <string>

#include <Eigen/Core>

#include "storetrack/calib/world_registration.hpp"
#include "storetrack/cli/command_line.hpp"

namespace storetrack::calibapp {

struct RegisterArgs {
  std::string rig;           ///< rig calibration file (the `rig` step's, world = S_r)
  std::string survey;        ///< storetrack-survey JSON, frame "w"
  std::string observations;  ///< observation CSV, point_id = survey mark id
  double sigma_px = 0;       ///< centroid sigma for rows without sigma_px (0: none given)
  double outlier_false_alarm = 0.01;
  bool keep_outliers = false;  ///< name failing marks but keep them in the fit
  std::string output;
  std::string residuals_csv;
};

void add_register(cli::Command& app, RegisterArgs& args);
int run_register(const RegisterArgs& args, std::ostream& out, std::ostream& err);

/// The rig file's joint covariance (file version 2, written by `rig`), else its per-camera
/// blocks (version 1: cross terms 0). `source` says which.
Eigen::MatrixXd input_calibration_covariance(const camera::RigCalibration& rig,
                                             std::string& source);

/// The registered calibration file (version 1 blocks) with the registration in its comment.
std::string registered_calibration_json(const calib::RegistrationResult& result,
                                        const std::string& rig_json_text, const RegisterArgs& args);

}  // namespace storetrack::calibapp
