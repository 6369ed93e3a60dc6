// What storetrack-host and storetrack-post build from the same inputs: the input files (read
// from disk by the host, from a recording's inputs channel by storetrack-post), the finished
// configuration and the processing chain. One setup, so that a replay processes with what the
// live run processed with.
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "host_options.hpp"
#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/clearance/sample_clearance.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"
#include "storetrack/output/chapter10_writer.hpp"
#include "storetrack/pipeline/calibration_health.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/survey/survey.hpp"

namespace storetrack::hostapp {

struct InputFiles {
  camera::RigCalibration rig;
  survey::RigidBodySurvey pylon, store;
};

/// The text of one input file: `kind` names it, `path` is the path the options give.
/// Throws std::runtime_error naming the file when it cannot.
using InputReader =
    std::function<std::string(output::RecordedInputKind kind, const std::string& path)>;

/// Reads the inputs the options name through `read`, and applies the options onto the
/// configuration (o.cfg), finished for the rig's cameras and units. Throws std::runtime_error
/// (file and reason, or the option and its range).
void load_inputs(HostOptions& o, const InputReader& read, InputFiles& in);

/// The processing chain: the aligner, the processor, whose matcher has its prior poses fitted to
/// the installation survey's initial marks (a warning names a body it cannot fit), and the
/// calibration health guard (nullptr when calibration_health.enabled is false). It keeps the
/// configuration and inputs it was made from: correct mode rebuilds the processor on the
/// corrected rig. Throws std::invalid_argument on a configuration the parts refuse.
struct ProcessingChain {
  HostConfig cfg;
  InputFiles in;
  std::unique_ptr<ingest::ExposureAligner> aligner;
  std::unique_ptr<pipeline::ExposureProcessor> processor;
  std::unique_ptr<pipeline::CalibrationHealthGuard> health;
  /// nullptr: no clearance geometry (the samples' clearance fields stay invalid).
  std::unique_ptr<clearance::SampleClearance> clearance;
  /// The last exposure's result, overwritten by the next (process_exposure): its marks'
  /// observations and loadings keep their storage instead of being allocated per exposure.
  pipeline::ExposureResult result;
};
ProcessingChain make_processing_chain(const HostConfig& cfg, const InputFiles& in);

/// The store-to-aircraft clearance of cfg.clearance_geometry (nullptr when none is configured),
/// for storetrack-host and storetrack-post alike: the geometry file (kind kClearanceGeometry, its
/// path as configured) and each STL file it names (kClearanceMesh, the path the geometry
/// resolves) read through `read`; every file read is appended to `read_files` when given (the
/// host records them). Throws (file, field or triangle named) on a file that cannot be read or
/// a mesh or field refused.
std::unique_ptr<clearance::SampleClearance> load_clearance(
    const HostConfig& cfg, const InputReader& read,
    std::vector<output::RecordedInputFile>* read_files = nullptr);

/// One exposure as storetrack-host processes it, live and replayed by storetrack-post: exclude
/// mode's filter, the processor, the calibration health test, the store-to-aircraft clearance of
/// a measured or extrapolated pose; in correct mode the chain's processor is rebuilt on the
/// corrected rig after an exposure whose test asks for it. The same steps in the same order, so a
/// replay's samples are the live run's in every mode.
struct ProcessedExposure {
  /// As processed: exclude mode's copy without the cameras declared moved (valid until the next
  /// call), else the exposure given.
  const pipeline::AlignedExposure* exposure = nullptr;
  /// chain.result: valid until the next call.
  pipeline::ExposureResult& result;
  bool processor_rebuilt = false;
  /// The clearance was evaluated (a measured or extrapolated pose): chain.clearance->parts()
  /// holds every part's until the next call; clearance_extrapolated: on the extrapolated pose.
  bool clearance_evaluated = false;
  bool clearance_extrapolated = false;
};
ProcessedExposure process_exposure(ProcessingChain& chain, const pipeline::AlignedExposure& e);

}  // namespace storetrack::hostapp
