// The subcommands of storetrack-calib: each reads its input, runs the library, writes its
// machine-readable result and prints a summary with units. Return the program's exit code.
#pragma once

#include <ostream>
#include <string>

#include "calib_cli.hpp"

namespace storetrack::calibapp {

int run_detect(const DetectArgs& args, std::ostream& out, std::ostream& err);
int run_intrinsic(const IntrinsicArgs& args, std::ostream& out, std::ostream& err);

/// The rig calibration file (docs/calibration-file.md) of one intrinsically calibrated camera;
/// the fit's summary goes into the camera's "comment" (ignored by readers). T_c_w is the
/// identity and its covariance zero until the rig and registration steps exist: stated there.
std::string intrinsic_calibration_json(const calib::IntrinsicResult& result, int camera_id,
                                       int unit_id, const calib::IntrinsicOptions& options);

}  // namespace storetrack::calibapp
