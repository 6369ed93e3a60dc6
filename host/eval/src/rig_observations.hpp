// A marks CSV sample's observations as the host's triangulator takes them, with the rig
// calibration the host used and the host's weights (internal; the noise floor and the LME's
// shared calibration).
#pragma once

#include <string>
#include <vector>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/eval/marks_csv.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "storetrack/uncertainty/calibration_factors.hpp"

namespace storetrack::eval::detail {

/// The sample's observations with a written pixel, each weighted as the host weighs it
/// ((sigma^2 I + the calibration's pixel covariance at the sample's position)^-1, factors of
/// `rig`), and per observation its camera's slot in the rig (rig.cameras index); throws
/// EvalInputError naming the file, line and camera when a camera is not in the rig.
inline std::vector<triangulate::Observation> rig_observations(
    const MarkSample& s, const camera::RigCalibration& rig,
    const uncertainty::CalibrationFactors& factors, const std::string& record_path,
    const std::string& rig_path, std::vector<int>* slots = nullptr) {
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
    const int slot = static_cast<int>(cam - rig.cameras.data());
    geometry::Mat2 W;
    if (uncertainty::view_information(factors, slot, *cam, s.p_w, o.sigma_px, W))
      t.information_px = W;
    obs.push_back(t);
    if (slots) slots->push_back(slot);
  }
  return obs;
}

}  // namespace storetrack::eval::detail
