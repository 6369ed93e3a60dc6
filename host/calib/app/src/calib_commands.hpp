// The subcommands of storetrack-calib: each reads its input, runs the library, writes its
// machine-readable result and prints a summary with units. Return the program's exit code.
#pragma once

#include <ostream>
#include <string>

#include "calib_cli.hpp"

namespace storetrack::calibapp {

int run_detect(const DetectArgs& args, std::ostream& out, std::ostream& err);
int run_intrinsic(const IntrinsicArgs& args, std::ostream& out, std::ostream& err);
int run_rig(const RigArgs& args, std::ostream& out, std::ostream& err);

/// Observation CSVs as one set (e.g. one per camera from `detect`). Throws ObservationFileError
/// naming both files when a (camera, frame, point) or a camera's image size appears twice
/// differently.
calib::ObservationSet merge_observation_files(const std::vector<std::string>& paths);

/// The rig calibration file (docs/calibration-file.md, version 1: a block per camera) of a rig
/// fit, T_c_w = T_c_r (world = S_r until the register step). The joint covariance of all
/// cameras (cross-camera terms included) and the fit summary go in the top-level "comment".
/// With `observations` (the fit's input), each camera's observed region (the points the fit used,
/// outliers not) is recorded (docs/calibration-file.md, "observed_region").
std::string rig_calibration_json(const calib::RigResult& result, int unit_id,
                                 const calib::RigOptions& options,
                                 const calib::ObservationSet* observations = nullptr);

/// The rig calibration file (docs/calibration-file.md) of one intrinsically calibrated camera;
/// the fit's summary goes into the camera's "comment" (ignored by readers). T_c_w is the
/// identity and its covariance zero until the rig and registration steps exist: stated there.
std::string intrinsic_calibration_json(const calib::IntrinsicResult& result, int camera_id,
                                       int unit_id, const calib::IntrinsicOptions& options,
                                       const calib::ObservationSet* observations = nullptr);

}  // namespace storetrack::calibapp
