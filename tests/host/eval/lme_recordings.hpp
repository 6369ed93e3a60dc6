// Scale-bar recordings of the simulator's scale_bars scenario as the host writes them: the
// host's ExposureProcessor on the simulator's fast-mode observations (truth ids), and the host's
// own marks CSV writer. The rig the host is given decides the calibration: the true rig with
// zero stated calibration covariance (a perfect calibration, stated as such) or the calibrated
// rig (truth + one error draw from its stated covariance, a new draw per seed).
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "diagnostic_csv.hpp"
#include "sim_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"

namespace storetrack::test {

/// The true rig with its calibration covariance set to zero: only centroid noise (and the
/// negligible sync term of static marks) remains in the host's stated u.
inline camera::RigCalibration perfect_rig(const sim::Simulator& sim) {
  camera::RigCalibration rig = sim.true_rig();
  for (camera::CalibratedCamera& c : rig.cameras) {
    c.intrinsic_covariance.setZero();
    c.extrinsic_covariance.setZero();
  }
  return rig;
}

/// Drops a camera's observation of a mark before the host sees it (visibility faults).
using ObservationFilter = std::function<bool(int camera_index, int mark_id)>;

/// Exposure 0 warms the tracker up (as a recording's first exposure does); exposures
/// 1..`exposures` are recorded. `results` (optional) receives the recorded exposures' results.
inline std::string scale_bar_marks_csv(const sim::Simulator& sim, const camera::RigCalibration& rig,
                                       int exposures,
                                       std::vector<pipeline::ExposureResult>* results = nullptr,
                                       const ObservationFilter& drop = {}) {
  pipeline::ExposureProcessor proc(rig, sim.pylon_survey(), sim.store_survey(),
                                   pipeline::ProcessorConfig{});
  std::string csv = std::string(hostapp::kMarksCsvHeader) + "\n";
  for (int k = 0; k <= exposures; ++k) {
    SimExposure in = make_exposure(sim, k);
    if (drop)
      for (size_t c = 0; c < in.ids.size(); ++c)
        for (int& id : in.ids[c])
          if (id >= 0 && drop(static_cast<int>(c), id)) id = -1;
    const pipeline::ExposureResult r = proc.process(in.exposure, in.ids);
    if (k == 0) continue;
    hostapp::format_marks_rows(in.exposure, r, csv);
    if (results) results->push_back(r);
  }
  return csv;
}

/// The bars with their TRUE lengths and zero calibration u (the truth is exact).
inline survey::ScaleBarSet true_bars(const sim::Simulator& sim) {
  survey::ScaleBarSet bars = sim.scale_bar_set(true);
  for (survey::ScaleBar& b : bars.bars)
    b.u_length_m = 0;
  return bars;
}

}  // namespace storetrack::test
