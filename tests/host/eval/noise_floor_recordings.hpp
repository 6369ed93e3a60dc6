// Static records of the simulator's static scene as the host writes them (the noise floor of
// storetrack-eval), and the truth to judge them: every mark's true world position (pylon and
// the store on its carriage do not move relative to the cameras), and the calibration error's
// effect on a mark: its noise-free true pixels triangulated with the rig the host used.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "host_recordings.hpp"
#include "storetrack/eval/marks_csv.hpp"
#include "storetrack/survey/survey.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "storetrack/uncertainty/calibration_factors.hpp"

namespace storetrack::test {

/// The marks CSV text of a static record: every exposure of the scenario through the host's
/// ExposureProcessor with `rig`, written by the host's own writer.
inline std::string simulated_static_record(const sim::Simulator& sim,
                                           const camera::RigCalibration& rig) {
  return host_marks_csv(sim, rig);
}

/// Every mark's true coordinates in the host's world frame (a perfect total station).
inline survey::RigidBodySurvey true_static_survey(const sim::Simulator& sim) {
  const time::TaiNs t = sim.trigger_tai_ns(0);
  survey::RigidBodySurvey s;
  s.name = "static scene marks, world frame";
  s.frame = 'w';
  s.mark_diameter_m = sim.true_pylon().mark_diameter_m;
  for (int id : sim.mark_ids())
    s.marks.push_back({id, true_mark_in_host_world(sim, id, t), 1e-6});
  return s;
}

/// Where the host's point settles without centroid noise: the true pixels of the cameras that
/// saw the mark in `sample`, weighted as the host weighs them ((sigma^2 I + the calibration's
/// pixel covariance at the sample's position)^-1, `factors` of `rig`), triangulated with `rig`.
inline geometry::Vec3 noise_free_position(const sim::Simulator& sim,
                                          const camera::RigCalibration& rig,
                                          const uncertainty::CalibrationFactors& factors,
                                          const eval::MarkSample& sample) {
  const sim::ExposureTruth truth = sim.truth(0);
  const sim::MarkTruth* mark = nullptr;
  for (const sim::MarkTruth& m : truth.marks)
    if (m.id == sample.mark_id) mark = &m;
  std::vector<triangulate::Observation> obs;
  for (const eval::MarkObservationSample& o : sample.observations) {
    size_t index = 0;
    while (rig.cameras[index].camera_id != o.camera_id)
      ++index;
    triangulate::Observation t;
    t.model = &rig.cameras[index].model;
    t.T_c_w = rig.cameras[index].T_c_w;
    t.pixel_px = mark->cameras[index].pixel;
    t.sigma_px = o.sigma_px;
    geometry::Mat2 W;
    if (uncertainty::view_information(factors, static_cast<int>(index), rig.cameras[index],
                                      sample.p_w, o.sigma_px, W))
      t.information_px = W;
    obs.push_back(t);
  }
  triangulate::Result r;
  triangulate::Options options;
  options.calibration_jacobians = false;
  if (!triangulate::triangulate(obs, options, r)) return geometry::Vec3::Constant(NAN);
  return r.p_w;
}

}  // namespace storetrack::test
