// What the host records from the simulator, shared by the evaluation tests: the host's
// ExposureProcessor on the simulator's fast-mode observations (truth ids) and the host's own
// marks CSV writer, with the rig the host is given (the true rig stated perfect, or a
// calibration draw).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "diagnostic_csv.hpp"
#include "sim_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"

namespace storetrack::test {

/// Drops a camera's observation of a mark before the host sees it (visibility faults).
using ObservationFilter = std::function<bool(int camera_index, int mark_id)>;

struct HostRecording {
  int first_recorded = 0;  ///< earlier exposures only warm the tracker up
  int last = -1;           ///< last exposure processed (-1: the scenario's last)
  std::vector<pipeline::ExposureResult>* results = nullptr;  ///< the recorded exposures' results
  ObservationFilter drop;
  /// Every centroid replaced by its mark's true projection, stated with sigma 0.001 px (the
  /// smallest the message carries): the calibration's error alone remains.
  bool true_pixels = false;
};

/// Replaces the centroids of `in` by the true projections of exposure k (perfect centroids).
inline void use_true_pixels(const sim::Simulator& sim, int k, SimExposure& in) {
  const sim::ExposureTruth truth = sim.truth(k);
  for (size_t c = 0; c < in.ids.size(); ++c)
    for (size_t j = 0; j < in.ids[c].size(); ++j)
      for (const sim::MarkTruth& m : truth.marks)
        if (m.id == in.ids[c][j]) {
          msg::MarkObservation& o = in.exposure.cameras[c].marks[j];
          o.x_px = static_cast<float>(m.cameras[c].pixel.x());
          o.y_px = static_cast<float>(m.cameras[c].pixel.y());
          o.sigma_px = 0.001f;
        }
}

/// The marks CSV text of exposures 0..last through the host's ExposureProcessor with `rig`,
/// those from `first_recorded` on written by the host's own writer.
inline std::string host_marks_csv(const sim::Simulator& sim, const camera::RigCalibration& rig,
                                  const HostRecording& recording = {}) {
  pipeline::ExposureProcessor proc(rig, sim.pylon_survey(), sim.store_survey(),
                                   pipeline::ProcessorConfig{});
  std::string csv = std::string(hostapp::kMarksCsvHeader) + "\n";
  const int last = recording.last >= 0 ? recording.last : sim.num_exposures() - 1;
  for (int k = 0; k <= last; ++k) {
    SimExposure in = make_exposure(sim, k);
    if (recording.true_pixels) use_true_pixels(sim, k, in);
    if (recording.drop)
      for (size_t c = 0; c < in.ids.size(); ++c)
        for (int& id : in.ids[c])
          if (id >= 0 && recording.drop(static_cast<int>(c), id)) id = -1;
    const pipeline::ExposureResult r = proc.process(in.exposure, in.ids);
    if (k < recording.first_recorded) continue;
    hostapp::format_marks_rows(in.exposure, r, csv);
    if (recording.results) recording.results->push_back(r);
  }
  return csv;
}

}  // namespace storetrack::test
