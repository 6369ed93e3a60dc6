// Rig calibration file (JSON, docs/calibration-file.md): cameras' intrinsics, extrinsics T_c_w
// and covariances. Read by both the unit (its own cameras) and the host (all of them).
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

#include "storetrack/camera/camera_model.hpp"

namespace storetrack::camera {

/// Thrown by the readers on malformed files; what() names the file, the JSON path and why.
class CalibrationFileError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct RigCalibration {
  std::vector<CalibratedCamera> cameras;
  const CalibratedCamera* find(int camera_id) const;
};

RigCalibration read_rig_calibration(const std::string& path);
RigCalibration parse_rig_calibration(const std::string& json_text, const std::string& origin);
void write_rig_calibration(const RigCalibration& rig, const std::string& path);
std::string format_rig_calibration(const RigCalibration& rig);

}  // namespace storetrack::camera
