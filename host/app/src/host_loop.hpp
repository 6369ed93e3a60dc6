// The real-time loop of storetrack-host: one thread, poll() on every input with the aligner's
// next deadline as timeout; each released exposure is processed, sent on iNET-X first, then
// handed to the RecordingWriter (files on their own thread). No file I/O on this thread.
#pragma once

#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <vector>

#include <nlohmann/json.hpp>

#include "latency.hpp"
#include "recording_writer.hpp"
#include "sample_gate.hpp"
#include "storetrack/clearance/sample_clearance.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"
#include "storetrack/ingest/receivers.hpp"
#include "storetrack/live/live_snapshot.hpp"
#include "storetrack/output/inetx.hpp"
#include "storetrack/pipeline/aligned_exposure.hpp"
#include "storetrack/pipeline/exposure_result.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::hostapp {

struct LoopLimits {
  double duration_s = 0;              ///< stop after this long (0: until signalled)
  double idle_exit_s = 0;             ///< stop this long after the last observation
  std::int64_t expect_exposures = 0;  ///< stop after this many exposures (0: no limit)
  bool progress = false;              ///< a progress line every second on stderr
};

struct LoopTotals {
  /// exposures: processed (every exposure the aligner released); samples_written: sent to the
  /// outputs; exposures = samples_written + withheld.total().
  std::uint64_t exposures = 0, samples_written = 0, valid_samples = 0, health_messages = 0;
  SamplesWithheld withheld;
  std::map<int, nlohmann::json> unit_health;  // keyed by the 8-bit unit id: <= 256 entries
  LatencyStats latency_complete, latency_all, latency_processing;
};

struct ProcessingChain;  // host_setup.hpp (host_options.hpp includes this file)
struct ProcessedExposure;

/// The parts the loop drives; all owned by main.
struct LoopParts {
  ingest::UdpReceiver& udp;
  std::vector<std::unique_ptr<ingest::CanFdReceiver>>& cans;
  /// The aligner, the processor and the calibration health guard (host_setup.hpp).
  ProcessingChain& chain;
  output::InetxSender* inetx;  ///< nullptr: no iNET-X
  RecordingWriter& recording;
  live::LivePublisher* live = nullptr;  ///< nullptr: no live page (--live)
};

class HostLoop {
 public:
  explicit HostLoop(const LoopParts& parts);
  /// Runs until `stop`, a limit, or a poll() failure; returns the exit code (0 or 1).
  int run(const LoopLimits& limits, const std::atomic<bool>& stop);
  const LoopTotals& totals() const { return totals_; }

 private:
  void on_message(const msg::AnyMessage& m);
  void process_ready();
  void record_aligner_event(ingest::RawSourceKind kind, time::MonotonicNs t);
  void process(const pipeline::AlignedExposure& e);
  void log_calibration_health(const pipeline::AlignedExposure& e, bool processor_rebuilt);
  void log_clearance(const pipeline::ExposureResult& r);
  void write_sample(const ProcessedExposure& done, time::MonotonicNs t_processing_start);

  LoopParts p_;
  ingest::ExposureAligner& aligner_;
  std::vector<bool> health_reported_;  ///< per camera: its baseline's end was logged
  LoopTotals totals_;
  std::vector<pipeline::AlignedExposure> ready_;
  time::MonotonicNs now_ = 0, t_first_input_ = 0, t_last_input_ = 0;
};

}  // namespace storetrack::hostapp
