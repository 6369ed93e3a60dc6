// storetrack-host: the host program. Receives MarkObservations (UDP and/or CAN FD), aligns
// exposures across cameras, identifies marks, solves the store pose with its uncertainty
// (ExposureProcessor) and writes every sample to the FTI sinks: iNET-X (first, it is the
// real-time path), Chapter 10 file, CSV. Counters at exit and as JSON (--stats-json).
// Exit codes: 0 ok, 1 runtime failure (sockets, disk), 2 bad arguments or input files.
//
// This file wires the parts together; find them by name:
//   host_options.*      command line          host_config.*  configuration JSON
//   host_loop.*         the real-time loop    recording_writer.*  all file output, own thread
//   diagnostic_csv.*    marks / rigid CSVs    stats.*        counters JSON and summary
//   latency.*           bounded latency statistics
//   host/live           the live page (--live): snapshot publisher and its server
#include <signal.h>

#include <spdlog/spdlog.h>
#include <atomic>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "host_config.hpp"
#include "host_loop.hpp"
#include "host_options.hpp"
#include "host_setup.hpp"
#include "recording_writer.hpp"
#include "stats.hpp"
#include "storetrack/clearance/sample_clearance.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"
#include "storetrack/ingest/receivers.hpp"
#include "storetrack/json/text_file.hpp"
#include "storetrack/live/live_server.hpp"
#include "storetrack/output/inetx.hpp"
#include "storetrack/pipeline/calibration_health.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/time/time.hpp"

namespace st = storetrack;
using st::hostapp::HostConfig;

namespace {

std::atomic<bool> g_stop{false};
void on_signal(int) {
  g_stop = true;
}

// The store-to-aircraft clearance (docs/clearance.md), when clearance.geometry is configured,
// read through `read`; the files read are kept in `read_files` for the recording. 0, or exit
// code 2 (a geometry file or mesh that cannot be read or is refused).
int start_clearance(const HostConfig& cfg, const st::hostapp::InputReader& read,
                    std::unique_ptr<st::clearance::SampleClearance>& out,
                    std::vector<st::output::RecordedInputFile>& read_files) {
  if (cfg.clearance_geometry.empty()) return 0;
  try {
    out = st::hostapp::load_clearance(cfg, read, &read_files);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-host: clearance.geometry '%s': %s\n",
                 cfg.clearance_geometry.c_str(), e.what());
    return 2;
  }
  spdlog::info(
      "storetrack-host: clearance: {} store part(s) against {} aircraft part(s) ({}), alarm "
      "when the k=2 lower bound is below {} m",
      out->model().store_parts(), out->model().aircraft_parts(), cfg.clearance_geometry,
      cfg.clearance_alarm_threshold_m);
  return 0;
}

// Reads the input files (the clearance geometry too) and applies the options onto the
// configuration; 0 or exit code 2.
int load_inputs(st::hostapp::HostOptions& o, st::hostapp::InputFiles& in,
                std::unique_ptr<st::clearance::SampleClearance>& clearance) {
  HostConfig& cfg = o.cfg;
  const auto from_disk = [](st::output::RecordedInputKind, const std::string& path) {
    return st::jsonfile::read_text_file(path);
  };
  try {
    st::hostapp::load_inputs(o, from_disk, in);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-host: %s\n", e.what());
    return 2;
  }
  if (!cfg.clearance_csv_path.empty() && cfg.clearance_geometry.empty()) {
    std::fprintf(stderr,
                 "storetrack-host: --clearance-csv '%s': no clearance geometry configured "
                 "(clearance.geometry)\n",
                 cfg.clearance_csv_path.c_str());
    return 2;
  }
  std::vector<st::output::RecordedInputFile> clearance_files;
  if (const int rc = start_clearance(cfg, from_disk, clearance, clearance_files); rc != 0)
    return rc;
  if (cfg.udp_port == 0 && cfg.can_interfaces.empty()) {
    std::fprintf(stderr, "storetrack-host: no input: give --udp-port and/or --can\n");
    return 2;
  }
  cfg.ch10.sync = o.ch10_sync == "none" ? st::output::Chapter10Sync::kNone
                                        : st::output::Chapter10Sync::kEveryPacket;
  cfg.ch10.existing = o.ch10_existing == "refuse" ? st::output::Chapter10Existing::kRefuse
                                                  : st::output::Chapter10Existing::kNumberNewFile;
  cfg.ch10.stores = {{cfg.processor.store_id, in.store.name}};
  cfg.ch10.raw_observations = cfg.record_raw_observations;
  // What reprocessing needs, in every Chapter 10 file: the input files' bytes as read (again,
  // after they parsed) and the command line (each argument followed by a NUL, as
  // /proc/PID/cmdline has it).
  if (!cfg.ch10_path.empty()) {
    using Kind = st::output::RecordedInputKind;
    const std::pair<Kind, const std::string*> files[] = {
        {Kind::kCalibration, &o.calibration_path},
        {Kind::kPylonSurvey, &o.pylon_path},
        {Kind::kStoreSurvey, &o.store_path},
        {Kind::kHostConfig, &o.config_path},
        {Kind::kInitialMarks, &o.initial_marks_path}};
    try {
      for (const auto& [kind, path] : files) {
        if (path->empty()) continue;
        const std::string text = st::jsonfile::read_text_file(*path);
        cfg.ch10.inputs.push_back({kind, *path, {text.begin(), text.end()}});
      }
    } catch (const std::exception& e) {
      std::fprintf(stderr, "storetrack-host: %s\n", e.what());
      return 2;
    }
    st::output::RecordedInputFile argv{Kind::kCommandLine, "argv", {}};
    for (const auto& arg : o.command_line) {
      argv.bytes.insert(argv.bytes.end(), arg.begin(), arg.end());
      argv.bytes.push_back(0);
    }
    cfg.ch10.inputs.push_back(std::move(argv));
    // The clearance geometry and its meshes as they were read (the geometry the samples used).
    for (auto& file : clearance_files)
      cfg.ch10.inputs.push_back(std::move(file));
  }
  return 0;
}

// Inputs: 0, or the exit code.
int open_inputs(const HostConfig& cfg, st::ingest::UdpReceiver& udp,
                std::vector<std::unique_ptr<st::ingest::CanFdReceiver>>& cans) {
  if (cfg.udp_port > 0) {
    const int rc = udp.open(cfg.udp_bind, static_cast<std::uint16_t>(cfg.udp_port), cfg.udp_group,
                            cfg.udp_interface);
    if (rc != 0) {
      std::fprintf(stderr, "storetrack-host: cannot receive UDP on %s:%d%s%s: %s\n",
                   cfg.udp_bind.c_str(), cfg.udp_port, cfg.udp_group.empty() ? "" : " group ",
                   cfg.udp_group.c_str(), std::strerror(-rc));
      return rc == -EINVAL ? 2 : 1;
    }
    const auto& uc = udp.counters();
    if (uc.receive_buffer_bytes < uc.receive_buffer_requested_bytes)
      spdlog::warn(
          "storetrack-host: UDP receive buffer {} KiB, not the {} KiB asked for (capped by "
          "net.core.rmem_max; raise it, or run with CAP_NET_ADMIN): bursts may be dropped "
          "(counted as udp.kernel_drops)",
          uc.receive_buffer_bytes / 1024, uc.receive_buffer_requested_bytes / 1024);
    for (const auto& src : cfg.udp_sources)
      udp.allow_source(src.unit_id, src.address);  // checked by finish_host_config
    if (cfg.udp_sources.empty())
      spdlog::warn(
          "storetrack-host: no udp.sources configured: datagrams from any sender accepted");
    else if (cfg.udp_kernel_filter)
      if (const int frc = udp.install_kernel_filter(); frc != 0)
        spdlog::warn(
            "storetrack-host: kernel source filter not installed ({}): other senders' datagrams "
            "are refused by the host only",
            std::strerror(-frc));
  }
  for (const auto& ifname : cfg.can_interfaces) {
    auto rx = std::make_unique<st::ingest::CanFdReceiver>();
    const int rc = rx->open(ifname);
    if (rc != 0) {
      std::fprintf(stderr, "storetrack-host: cannot open CAN FD interface '%s': %s\n",
                   ifname.c_str(), std::strerror(-rc));
      return rc == -ENODEV ? 2 : 1;
    }
    cans.push_back(std::move(rx));
  }
  return 0;
}

// Sinks: iNET-X on the real-time thread, the files on the RecordingWriter's. 0 or exit code.
int open_sinks(const HostConfig& cfg, st::output::InetxSender& inetx, bool& inetx_open,
               st::hostapp::RecordingWriter& recording) {
  if (!cfg.inetx_destination.empty()) {
    const int rc = inetx.open(cfg.inetx_destination, cfg.inetx_stream_id);
    if (rc != 0) {
      std::fprintf(stderr, "storetrack-host: --inetx '%s': %s\n", cfg.inetx_destination.c_str(),
                   rc == -EINVAL ? "expected a.b.c.d:port" : std::strerror(-rc));
      return rc == -EINVAL ? 2 : 1;
    }
    inetx_open = true;
  }
  if (!cfg.ch10_path.empty()) {
    const int rc = recording.open_ch10(cfg.ch10_path, cfg.ch10);
    if (rc != 0) {
      std::fprintf(stderr, "storetrack-host: cannot write Chapter 10 file '%s': %s\n",
                   cfg.ch10_path.c_str(),
                   rc == -EEXIST ? "it exists (--ch10-existing refuse, or no free number)"
                                 : std::strerror(-rc));
      return 2;
    }
    const std::string& file = recording.ch10().files().front();
    if (file != cfg.ch10_path) {
      spdlog::warn("storetrack-host: Chapter 10 file '{}' exists and is kept; recording to '{}'",
                   cfg.ch10_path, file);
    }
    spdlog::info("storetrack-host: recording Chapter 10 to '{}'", file);
  }
  const std::pair<const std::string*, int (st::hostapp::RecordingWriter::*)(const std::string&)>
      csvs[] = {{&cfg.csv_path, &st::hostapp::RecordingWriter::open_csv},
                {&cfg.marks_csv_path, &st::hostapp::RecordingWriter::open_marks_csv},
                {&cfg.rigid_csv_path, &st::hostapp::RecordingWriter::open_rigid_csv},
                {&cfg.clearance_csv_path, &st::hostapp::RecordingWriter::open_clearance_csv}};
  for (const auto& [path, open] : csvs) {
    if (path->empty()) continue;
    if ((recording.*open)(*path) != 0) {
      std::fprintf(stderr, "storetrack-host: cannot write '%s'\n", path->c_str());
      return 2;
    }
  }
  return 0;
}

// The live page (--live ADDR:PORT): its publisher for the loop and its server, started; prints
// the URL. 0, or exit code 2 (bad address) / 1 (cannot listen).
int start_live_view(const st::hostapp::HostOptions& o, const st::hostapp::InputFiles& in,
                    std::unique_ptr<st::live::LivePublisher>& publisher,
                    std::unique_ptr<st::live::LiveServer>& server) {
  if (o.live_address.empty()) return 0;
  st::live::LiveServerConfig config;
  try {
    config.address = st::live::parse_live_address(o.live_address);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-host: %s\n", e.what());
    return 2;
  }
  config.max_clients = o.live_max_clients;
  st::live::LiveRig rig;
  for (const auto& c : in.rig.cameras) {
    rig.camera_ids.push_back(c.camera_id);
    rig.unit_ids.push_back(c.unit_id);
  }
  try {
    publisher = std::make_unique<st::live::LivePublisher>(rig);
    server = std::make_unique<st::live::LiveServer>(
        config, st::live::LiveScene{in.rig, in.pylon, in.store, o.cfg.live_store_envelope_p},
        *publisher);
    server->start();
  } catch (const std::invalid_argument& e) {
    std::fprintf(stderr, "storetrack-host: %s\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-host: %s\n", e.what());
    return 1;
  }
  if (config.address.host == "0.0.0.0")
    spdlog::warn("storetrack-host: the live page is served on every interface (--live 0.0.0.0)");
  // stdout, flushed: scripts and the operator read the URL while the host runs.
  std::printf("storetrack-host: live view at %s\n", server->url().c_str());
  std::fflush(stdout);
  return 0;
}

// The calibration health test's settings (docs/calibration-health.md), or that it is off.
void log_calibration_health(const HostConfig& cfg,
                            const st::pipeline::CalibrationHealthGuard* guard) {
  if (guard == nullptr) {
    spdlog::warn("storetrack-host: calibration health test off (calibration_health.enabled)");
    return;
  }
  const auto& hc = cfg.calibration_health;
  static constexpr const char* kModes[] = {"flag", "correct", "exclude"};
  spdlog::info(
      "storetrack-host: calibration health: mode {}, windows of {} exposures, false alarm "
      "probability {:g} per camera and window (chi-square(6) > {:.1f}), baseline {} exposures; "
      "cameras seeing fewer than {} pylon marks are named at the baseline's end",
      kModes[static_cast<int>(cfg.calibration_health_mode)], hc.window_exposures,
      hc.false_alarm_probability, guard->monitor().threshold(),
      hc.window_exposures * hc.baseline_windows, hc.min_pylon_marks);
}

}  // namespace

int main(int argc, char** argv) {
  st::hostapp::HostOptions options;
  if (const int rc = st::hostapp::parse_host_options(argc, argv, options); rc >= 0) return rc;
  options.command_line.assign(argv, argv + argc);
  spdlog::set_level(spdlog::level::from_str(options.log_level));
  st::hostapp::InputFiles in;
  std::unique_ptr<st::clearance::SampleClearance> clearance;
  if (const int rc = load_inputs(options, in, clearance); rc != 0) return rc;
  const HostConfig& cfg = options.cfg;

  st::hostapp::ProcessingChain chain;
  try {
    chain = st::hostapp::make_processing_chain(cfg, in);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-host: bad configuration: %s\n", e.what());
    return 2;
  }
  st::ingest::ExposureAligner& aligner = *chain.aligner;
  log_calibration_health(cfg, chain.health.get());

  st::ingest::UdpReceiver udp;
  std::vector<std::unique_ptr<st::ingest::CanFdReceiver>> cans;
  if (const int rc = open_inputs(cfg, udp, cans); rc != 0) return rc;
  st::output::InetxSender inetx;
  bool inetx_open = false;
  st::hostapp::RecordingWriter recording(cfg.recording_queue_items);
  if (const int rc = open_sinks(cfg, inetx, inetx_open, recording); rc != 0) return rc;
  std::unique_ptr<st::live::LivePublisher> live_publisher;
  std::unique_ptr<st::live::LiveServer> live_server;
  if (const int rc = start_live_view(options, in, live_publisher, live_server); rc != 0) return rc;
  recording.start();

  signal(SIGINT, on_signal);
  signal(SIGTERM, on_signal);
  spdlog::info("storetrack-host: {} cameras, inputs: {}{}, waiting for observations",
               in.rig.cameras.size(), cfg.udp_port ? fmt::format("udp:{} ", cfg.udp_port) : "",
               cans.empty() ? "" : fmt::format("{} CAN interface(s)", cans.size()));
  const st::time::MonotonicNs t_start = st::time::monotonic_now_ns();
  chain.clearance = std::move(clearance);
  const st::hostapp::LoopParts parts{
      udp, cans, chain, inetx_open ? &inetx : nullptr, recording, live_publisher.get()};
  st::hostapp::HostLoop loop(parts);
  int exit_code = loop.run(options.limits, g_stop);
  if (live_server) live_server->stop();
  recording.stop();

  const st::hostapp::StatsSources sources{
      cfg,
      udp,
      cans,
      aligner,
      *chain.processor,
      inetx,
      recording,
      loop.totals(),
      static_cast<double>(st::time::monotonic_now_ns() - t_start) * 1e-9,
      chain.health.get(),
      chain.clearance.get()};
  st::hostapp::print_summary(sources);
  nlohmann::json stats = st::hostapp::host_stats_json(sources);
  if (live_server)
    stats["live"] =
        st::hostapp::live_stats_json(live_server->counters(), live_publisher->publications());
  if (!options.stats_json_path.empty() &&
      !st::hostapp::write_stats_json(stats, options.stats_json_path)) {
    std::fprintf(stderr, "storetrack-host: cannot write '%s'\n", options.stats_json_path.c_str());
    exit_code = 1;
  }
  if (recording.had_errors()) exit_code = 1;
  return exit_code;
}
