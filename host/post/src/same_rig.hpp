// A substituted calibration must be of the rig the recording was made with: the same cameras
// (unit and camera ids). Another rig's calibration would replay observations through the wrong
// cameras' models, or none.
#pragma once

#include <string>

#include "storetrack/camera/calibration_file.hpp"

namespace storetrack::post {

/// Throws std::runtime_error naming `substitute_path` and both camera lists when `substitute`'s
/// cameras are not `recorded`'s (the calibration `recording_file` carries).
void check_same_rig(const camera::RigCalibration& recorded, const std::string& recording_file,
                    const camera::RigCalibration& substitute, const std::string& substitute_path);

}  // namespace storetrack::post
