// Pendulum runs of the simulator as the host records them: the simulator's pendulum scenario
// (one seed per run: centroid noise, timing jitter and, with the calibrated rig, a calibration
// draw), the host's ExposureProcessor tracking the board as its "store", and the host's own
// marks CSV writer (the input of storetrack-eval pendulum).
#pragma once

#include <cstdint>
#include <string>

#include "diagnostic_csv.hpp"
#include "sim_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/sim/pendulum_truth.hpp"

namespace storetrack::test {

/// A counter-clockwise run is the mirror release: theta0 -> -theta0 (same plane and pivot).
inline sim::Scenario pendulum_scenario(bool counter_clockwise) {
  sim::Scenario sc = sim::load_scenario(scenario_path("pendulum"));
  if (counter_clockwise) sc.pendulum_motion.theta0_rad = -sc.pendulum_motion.theta0_rad;
  return sc;
}

/// The marks CSV text of one run: every `stride`-th of its first `exposures` exposures (all when
/// <= 0). `true_rig`: the host gets the true calibration (random errors only), else the seed's
/// calibration draw.
inline std::string simulated_pendulum_csv(const sim::Scenario& scenario, std::uint64_t seed,
                                          bool true_rig, int exposures = 0, int stride = 1) {
  const sim::Simulator sim(scenario, seed);
  pipeline::ExposureProcessor proc(true_rig ? sim.true_rig() : sim.calibrated_rig(),
                                   sim.pylon_survey(), sim.pendulum_survey(),
                                   pipeline::ProcessorConfig{});
  const int n = exposures > 0 ? std::min(exposures, sim.num_exposures()) : sim.num_exposures();
  std::string csv = std::string(hostapp::kMarksCsvHeader) + "\n";
  for (int k = 0; k < n; k += stride) {
    const SimExposure in = make_exposure(sim, k);
    const pipeline::ExposureResult r = proc.process(in.exposure, in.ids);
    hostapp::format_marks_rows(in.exposure, r, csv);
  }
  return csv;
}

}  // namespace storetrack::test
