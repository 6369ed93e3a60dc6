// The simulated exposures the host benchmarks replay, and the host's processor for them: one
// setup for every benchmark that times the host's per-exposure work, so that their figures
// speak of the same inputs. Needs STORETRACK_SCENARIO_DIR (the benchmark's compile definition).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/sim/simulator.hpp"

namespace storetrack::bench {

/// Every exposure of a simulated run as the aligner hands it to the processor (one observation
/// per camera, the first camera's trigger_seq), with the simulator's truth ids.
struct SimulatedExposures {
  SimulatedExposures(const sim::Scenario& scenario, std::uint64_t seed) : sim(scenario, seed) {
    for (int k = 0; k < sim.num_exposures(); ++k) {
      pipeline::AlignedExposure ex;
      pipeline::MarkIds ids(static_cast<std::size_t>(sim.num_cameras()));
      ex.cameras.resize(ids.size());
      for (int c = 0; c < sim.num_cameras(); ++c)
        sim.observe(k, c, ex.cameras[static_cast<std::size_t>(c)],
                    &ids[static_cast<std::size_t>(c)]);
      ex.trigger_seq = ex.cameras[0].trigger_seq;
      exposures.push_back(ex);
      truth_ids.push_back(ids);
    }
  }

  sim::Simulator sim;
  std::vector<pipeline::AlignedExposure> exposures;
  std::vector<pipeline::MarkIds> truth_ids;  ///< [exposure][camera][observation]
};

/// The store-separation scenario (4 cameras, 23 marks), seed 3, simulated once per process.
inline const SimulatedExposures& store_separation() {
  static const SimulatedExposures d(
      sim::load_scenario(std::string(STORETRACK_SCENARIO_DIR) + "/store_separation.json"), 3);
  return d;
}

/// The host's processor for the simulator's rig and surveys, with the pylon and the store
/// expected at the scenario's start (prior covariance 1e-4 on each pose component).
inline pipeline::ExposureProcessor make_processor(const sim::Simulator& sim) {
  pipeline::ExposureProcessor proc(sim.calibrated_rig(), sim.pylon_survey(), sim.store_survey(),
                                   pipeline::ProcessorConfig{});
  const geometry::Mat6 prior = geometry::Mat6::Identity() * 1e-4;
  proc.matcher().set_prior_pose("pylon", sim.scenario().T_w_p, prior);
  proc.matcher().set_prior_pose("store", sim.scenario().T_w_p * sim.scenario().separation.T_p_s0,
                                prior);
  return proc;
}

}  // namespace storetrack::bench
