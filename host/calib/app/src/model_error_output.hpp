// The model error check (calib/model_error_check.hpp) of intrinsic and rig: printed, and written
// into the calibration file as each camera's "model_error" section (docs/calibration-file.md).
#pragma once

#include <ostream>
#include <string>
#include <vector>

#include "storetrack/calib/model_error_check.hpp"

namespace storetrack::calibapp {

/// One line per camera: "camera N: noise dominates: ..." or "model error dominates here: ...".
void print_model_error(const std::vector<calib::ModelErrorCheck>& checks, std::ostream& out);

/// `calibration_json` with the "model_error" section of each checked camera added.
std::string with_model_error(const std::string& calibration_json,
                             const std::vector<calib::ModelErrorCheck>& checks);

}  // namespace storetrack::calibapp
