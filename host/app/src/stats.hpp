// storetrack-host's counters: the --stats-json document and the summary printed at exit. Every
// drop and error of every part has a counter here (docs/reliability.md).
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "host_config.hpp"
#include "host_loop.hpp"
#include "recording_writer.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"
#include "storetrack/ingest/receivers.hpp"
#include "storetrack/live/live_server.hpp"
#include "storetrack/output/inetx.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"

namespace storetrack::hostapp {

/// Everything the counters are read from, after the run.
struct StatsSources {
  const HostConfig& cfg;
  const ingest::UdpReceiver& udp;
  const std::vector<std::unique_ptr<ingest::CanFdReceiver>>& cans;
  const ingest::ExposureAligner& aligner;
  const pipeline::ExposureProcessor& processor;
  const output::InetxSender& inetx;
  const RecordingWriter& recording;
  const LoopTotals& totals;
  double wall_time_s = 0;
  /// nullptr: calibration_health.enabled false.
  const pipeline::CalibrationHealthGuard* health = nullptr;
  /// nullptr: no clearance geometry configured.
  const clearance::SampleClearance* clearance = nullptr;
};

nlohmann::json host_stats_json(const StatsSources& s);
/// Per camera: monitored, moved, windows, alarms, the motion estimate (stats "calibration_health").
nlohmann::json calibration_health_json(const pipeline::CalibrationHealthGuard& guard);
/// Samples evaluated, alarm samples and alarm episodes, the threshold (stats "clearance").
nlohmann::json clearance_json(const clearance::SampleClearance& clearance);
/// Chapter 10 counters, the files written and the recording queue (stats "recording").
nlohmann::json recording_stats_json(const RecordingWriter& recording,
                                    const std::string& requested_ch10_path);
/// One counter per output and kind of failure (stats "outputs"; tools read these keys).
nlohmann::json outputs_stats_json(const output::InetxSender& inetx,
                                  const RecordingWriter& recording);
/// The live page's server (stats "live", with --live): requests, clients, refusals, drops.
nlohmann::json live_stats_json(const live::LiveServerCounters& c, std::uint64_t publications);
void print_summary(const StatsSources& s);
/// Writes `stats` to `path`; false when it could not.
bool write_stats_json(const nlohmann::json& stats, const std::string& path);

}  // namespace storetrack::hostapp
