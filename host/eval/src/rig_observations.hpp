// A marks CSV sample's observations as the host's triangulator takes them, with the rig
// calibration the host used (internal; the noise floor and the LME's shared calibration).
#pragma once

#include <string>
#include <vector>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/eval/marks_csv.hpp"
#include "storetrack/triangulate/triangulate.hpp"

namespace storetrack::eval::detail {

/// The sample's observations with a written pixel, and per observation its camera's slot in
/// the rig (rig.cameras index); throws EvalInputError naming the file, line and camera when a
/// camera is not in the rig.
inline std::vector<triangulate::Observation> rig_observations(const MarkSample& s,
                                                              const camera::RigCalibration& rig,
                                                              const std::string& record_path,
                                                              const std::string& rig_path,
                                                              std::vector<int>* slots = nullptr) {
  std::vector<triangulate::Observation> obs;
  for (const MarkObservationSample& o : s.observations) {
    const camera::CalibratedCamera* cam = rig.find(o.camera_id);
    if (!cam)
      throw EvalInputError(record_path + ":" + std::to_string(s.line) + ": camera_id: camera " +
                           std::to_string(o.camera_id) + " is not in the rig " + rig_path);
    if (!o.pixel_px.allFinite()) continue;
    triangulate::Observation t;
    t.model = &cam->model;
    t.T_c_w = cam->T_c_w;
    t.pixel_px = o.pixel_px;
    t.sigma_px = o.sigma_px;
    obs.push_back(t);
    if (slots) slots->push_back(static_cast<int>(cam - rig.cameras.data()));
  }
  return obs;
}

}  // namespace storetrack::eval::detail
