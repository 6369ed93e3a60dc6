// Scale-bar recordings of the simulator's scale_bars scenario as the host writes them: the
// host's ExposureProcessor on the simulator's fast-mode observations (truth ids), and the host's
// own marks CSV writer. The rig the host is given decides the calibration: the true rig with
// zero stated calibration covariance (a perfect calibration, stated as such) or the calibrated
// rig (truth + one error draw from its stated covariance, a new draw per seed).
#pragma once

#include <string>
#include <vector>

#include "host_recordings.hpp"

namespace storetrack::test {

/// Exposure 0 warms the tracker up (as a recording's first exposure does); exposures
/// 1..`exposures` are recorded. `results` (optional) receives the recorded exposures' results.
inline std::string scale_bar_marks_csv(const sim::Simulator& sim, const camera::RigCalibration& rig,
                                       int exposures,
                                       std::vector<pipeline::ExposureResult>* results = nullptr,
                                       const ObservationFilter& drop = {}) {
  return host_marks_csv(sim, rig, {1, exposures, results, drop});
}

/// The bars with their TRUE lengths and zero calibration u (the truth is exact).
inline survey::ScaleBarSet true_bars(const sim::Simulator& sim) {
  survey::ScaleBarSet bars = sim.scale_bar_set(true);
  for (survey::ScaleBar& b : bars.bars)
    b.u_length_m = 0;
  return bars;
}

}  // namespace storetrack::test
