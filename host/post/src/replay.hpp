// The replay: a recording's raw channel given to the host's own aligner and processor, each
// message and each of the aligner's clock events at the host loop time it had live. The aligner
// depends only on those inputs and times, and the processor only on the exposures in release
// order, so with the recorded inputs the samples are the live run's, bit for bit.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "diagnostic_csv.hpp"
#include "host_setup.hpp"
#include "sample_gate.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/output/chapter10_reader.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/smooth/pose_smoother.hpp"

namespace storetrack::post {

struct ReplayCounters {
  std::uint64_t records = 0;
  std::uint64_t refused_live = 0;     ///< messages the host's receiver refused: not replayed
  std::uint64_t undecodable = 0;      ///< accepted live, not decodable now (a damaged record)
  std::uint64_t observations = 0;     ///< MarkObservations given to the aligner
  std::uint64_t health_messages = 0;  ///< UnitHealth (not an aligner input)
  std::uint64_t deadline_events = 0;  ///< ExposureAligner::poll calls repeated
  std::uint64_t flush_events = 0;     ///< the host's final ExposureAligner::flush
  std::uint64_t pending_at_end = 0;   ///< exposures still pending after the last record
  std::uint64_t unknown_kind = 0;     ///< records of a kind this replay does not know
  std::uint64_t exposures = 0;        ///< exposures processed
  hostapp::SamplesWithheld withheld;  ///< processed, not written (as live)
};

class Replay {
 public:
  /// The chain the recording's inputs make (hostapp::make_processing_chain): its aligner, its
  /// processor and its calibration health guard, driven as the host drives them.
  explicit Replay(hostapp::ProcessingChain& chain) : chain_(chain) {}

  /// One raw-channel record, in recorded order.
  void feed(const ch10read::RawObservation& record);
  /// After the last record. A recording without the host's final flush (a host killed, a file
  /// cut) is not flushed here: its samples are then what the live aligner had released by its
  /// last record, a prefix of the live run's, and what was still pending is counted
  /// (counters().pending_at_end).
  void finish();

  /// Keep each written sample's pose solution for the smoother (measurements()).
  void collect_measurements(bool on) { collect_ = on; }

  /// Write each written sample's every-part clearance rows to `file` (--clearance-csv: the
  /// host's format and formatter; the file counts its write errors). nullptr: none.
  void write_clearance_rows(hostapp::CsvFile* file) { clearance_csv_ = file; }

  /// Called with each written sample's processing result (--differences-csv).
  void on_sample(std::function<void(const pipeline::ExposureResult&)> f) {
    on_sample_ = std::move(f);
  }

  /// Called with every processed exposure (written or withheld) and its processing result
  /// (--report: camera usage and residuals); processor_rebuilt: correct mode rebuilt the chain's
  /// processor on a corrected rig after this exposure (the next ones use it).
  void on_exposure(
      std::function<void(const pipeline::AlignedExposure&, const pipeline::ExposureResult&,
                         bool written, bool processor_rebuilt)>
          f) {
    on_exposure_ = std::move(f);
  }

  /// The samples written, in the order the host wrote them.
  const std::vector<msg::FtiSample>& samples() const { return samples_; }
  /// The written samples' pose solutions as the smoother takes them (collect_measurements).
  const std::vector<smooth::PoseMeasurement>& measurements() const { return measurements_; }
  const ReplayCounters& counters() const { return counters_; }

 private:
  void process_ready();

  hostapp::ProcessingChain& chain_;
  std::vector<pipeline::AlignedExposure> ready_;
  std::vector<msg::FtiSample> samples_;
  bool collect_ = false;
  std::vector<smooth::PoseMeasurement> measurements_;
  std::function<void(const pipeline::ExposureResult&)> on_sample_;
  std::function<void(const pipeline::AlignedExposure&, const pipeline::ExposureResult&, bool, bool)>
      on_exposure_;
  ReplayCounters counters_;
  hostapp::CsvFile* clearance_csv_ = nullptr;
  std::string clearance_rows_;  ///< reused: one sample's rows
};

}  // namespace storetrack::post
