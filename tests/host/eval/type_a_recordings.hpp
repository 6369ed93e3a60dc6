// Repeated static recordings of the simulator's static scene as the host writes them: one
// simulator seed per repetition (independent calibration draw, survey errors and centroid
// noise, i.e. an independent set-up as in SisTrO's 20 tests), the host's ExposureProcessor, and
// the host's own marks CSV writer. The reference: the pylon marks' true world coordinates.
#pragma once

#include <cstdint>
#include <string>

#include "diagnostic_csv.hpp"
#include "sim_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/survey/survey.hpp"

namespace storetrack::test {

/// The marks CSV text of one repetition: exposure k0 warms the tracker up (as a recording's
/// first exposure does), exposure k0 + 1 is the one recorded.
inline std::string simulated_marks_csv(const sim::Scenario& scenario, std::uint64_t seed) {
  const sim::Simulator sim(scenario, seed);
  pipeline::ExposureProcessor proc(sim.calibrated_rig(), sim.pylon_survey(), sim.store_survey(),
                                   pipeline::ProcessorConfig{});
  const int k0 = static_cast<int>(seed % static_cast<std::uint64_t>(sim.num_exposures() - 1));
  std::string csv = std::string(hostapp::kMarksCsvHeader) + "\n";
  for (int k = k0; k < k0 + 2; ++k) {
    const SimExposure in = make_exposure(sim, k);
    const pipeline::ExposureResult r = proc.process(in.exposure, in.ids);
    if (k > k0) hostapp::format_marks_rows(in.exposure, r, csv);
  }
  return csv;
}

/// The pylon marks' true coordinates in the host's world frame (a perfect total station).
inline survey::RigidBodySurvey true_world_survey(const sim::Scenario& scenario) {
  const sim::Simulator sim(scenario, 1);
  const time::TaiNs t = sim.trigger_tai_ns(0);
  survey::RigidBodySurvey s;
  s.name = "pylon marks, world frame";
  s.frame = 'w';
  s.mark_diameter_m = sim.true_pylon().mark_diameter_m;
  for (const survey::SurveyedMark& m : sim.true_pylon().marks)
    s.marks.push_back({m.id, true_mark_in_host_world(sim, m.id, t), 1e-6});
  return s;
}

}  // namespace storetrack::test
