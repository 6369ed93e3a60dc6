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
#include "recording_writer.hpp"
#include "stats.hpp"
#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"
#include "storetrack/ingest/receivers.hpp"
#include "storetrack/json/text_file.hpp"
#include "storetrack/match/mark_matcher.hpp"
#include "storetrack/output/inetx.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/survey/survey.hpp"
#include "storetrack/time/time.hpp"

namespace st = storetrack;
using st::hostapp::HostConfig;

namespace {

std::atomic<bool> g_stop{false};
void on_signal(int) {
  g_stop = true;
}

struct InputFiles {
  st::camera::RigCalibration rig;
  st::survey::RigidBodySurvey pylon, store;
};

// Reads the input files and applies the options onto the configuration; 0 or exit code 2.
int load_inputs(st::hostapp::HostOptions& o, InputFiles& in) {
  HostConfig& cfg = o.cfg;
  try {
    if (!o.config_path.empty()) st::hostapp::load_host_config(o.config_path, cfg);
    in.rig = st::camera::read_rig_calibration(o.calibration_path);
    in.pylon = st::survey::read_survey(o.pylon_path);
    in.store = st::survey::read_survey(o.store_path);
    if (!o.initial_marks_path.empty())
      cfg.initial_marks_w = st::hostapp::load_initial_marks(o.initial_marks_path);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-host: %s\n", e.what());
    return 2;
  }
  if (in.rig.cameras.empty() || in.rig.cameras.size() > 32) {
    std::fprintf(stderr, "storetrack-host: %s: the rig needs 1..32 cameras (has %zu)\n",
                 o.calibration_path.c_str(), in.rig.cameras.size());
    return 2;
  }
  if (cfg.udp_port == 0 && cfg.can_interfaces.empty()) {
    std::fprintf(stderr, "storetrack-host: no input: give --udp-port and/or --can\n");
    return 2;
  }
  try {
    if (o.max_wait_ms > 0) st::hostapp::set_max_wait_ms(cfg, o.max_wait_ms, "--max-wait-ms");
    if (o.min_cameras > 0) cfg.aligner.min_cameras = o.min_cameras;
    for (const auto& text : o.udp_sources)
      cfg.udp_sources.push_back(st::hostapp::parse_udp_source(text));
    if (o.no_udp_kernel_filter) cfg.udp_kernel_filter = false;
    std::vector<int> camera_ids, unit_ids;
    for (const auto& c : in.rig.cameras) {
      camera_ids.push_back(c.camera_id);
      unit_ids.push_back(c.unit_id);
    }
    st::hostapp::finish_host_config(cfg, camera_ids, unit_ids);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-host: %s\n", e.what());
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
  }
  return 0;
}

// Mark identification: the processor's MarkMatcher. Its prior poses (acquisition, and
// re-acquisition of a body lost for longer than its track gap) are fitted to the installation
// survey's initial mark positions; without them it cannot acquire a body.
void set_prior_poses(const HostConfig& cfg, const InputFiles& in,
                     st::pipeline::ExposureProcessor& processor) {
  std::vector<st::geometry::Transform> fitted;
  for (const auto* body : {&in.pylon, &in.store}) {
    st::geometry::Transform T_w_b;
    st::geometry::Mat6 cov;
    if (st::match::fit_body_pose(*body, cfg.initial_marks_w, cfg.initial_marks_sigma_m, T_w_b,
                                 cov)) {
      processor.matcher().set_prior_pose(body->name, T_w_b, cov);
      fitted.push_back(T_w_b);
    } else {
      spdlog::warn(
          "storetrack-host: no prior pose for '{}' (needs >= 3 non-collinear of its marks in "
          "--initial-marks): its marks cannot be identified",
          body->name);
    }
  }
  // The store's region relative to the pylon (re-acquisition), around its installation pose.
  if (cfg.store_region.valid && fitted.size() == 2) {
    st::match::BodyRegion region;
    region.reference_body = in.pylon.name;
    region.T_ref_b_nominal = fitted[0].inverse() * fitted[1];
    region.max_rotation_rad = cfg.store_region.max_rotation_rad;
    region.min_offset_m = cfg.store_region.min_offset_m;
    region.max_offset_m = cfg.store_region.max_offset_m;
    processor.matcher().set_region(in.store.name, region);
  }
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
                {&cfg.rigid_csv_path, &st::hostapp::RecordingWriter::open_rigid_csv}};
  for (const auto& [path, open] : csvs) {
    if (path->empty()) continue;
    if ((recording.*open)(*path) != 0) {
      std::fprintf(stderr, "storetrack-host: cannot write '%s'\n", path->c_str());
      return 2;
    }
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  st::hostapp::HostOptions options;
  if (const int rc = st::hostapp::parse_host_options(argc, argv, options); rc >= 0) return rc;
  options.command_line.assign(argv, argv + argc);
  spdlog::set_level(spdlog::level::from_str(options.log_level));
  InputFiles in;
  if (const int rc = load_inputs(options, in); rc != 0) return rc;
  const HostConfig& cfg = options.cfg;

  // Processing chain.
  std::unique_ptr<st::pipeline::ExposureProcessor> processor;
  std::unique_ptr<st::ingest::ExposureAligner> aligner;
  try {
    processor = std::make_unique<st::pipeline::ExposureProcessor>(in.rig, in.pylon, in.store,
                                                                  cfg.processor);
    aligner = std::make_unique<st::ingest::ExposureAligner>(cfg.aligner);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-host: bad configuration: %s\n", e.what());
    return 2;
  }
  set_prior_poses(cfg, in, *processor);

  st::ingest::UdpReceiver udp;
  std::vector<std::unique_ptr<st::ingest::CanFdReceiver>> cans;
  if (const int rc = open_inputs(cfg, udp, cans); rc != 0) return rc;
  st::output::InetxSender inetx;
  bool inetx_open = false;
  st::hostapp::RecordingWriter recording(cfg.recording_queue_items);
  if (const int rc = open_sinks(cfg, inetx, inetx_open, recording); rc != 0) return rc;
  recording.start();

  signal(SIGINT, on_signal);
  signal(SIGTERM, on_signal);
  spdlog::info("storetrack-host: {} cameras, inputs: {}{}, waiting for observations",
               in.rig.cameras.size(), cfg.udp_port ? fmt::format("udp:{} ", cfg.udp_port) : "",
               cans.empty() ? "" : fmt::format("{} CAN interface(s)", cans.size()));
  const st::time::MonotonicNs t_start = st::time::monotonic_now_ns();
  st::hostapp::HostLoop loop(
      {udp, cans, *aligner, *processor, inetx_open ? &inetx : nullptr, recording});
  int exit_code = loop.run(options.limits, g_stop);
  recording.stop();

  const st::hostapp::StatsSources sources{
      cfg,       udp,           cans,
      *aligner,  *processor,    inetx,
      recording, loop.totals(), static_cast<double>(st::time::monotonic_now_ns() - t_start) * 1e-9};
  st::hostapp::print_summary(sources);
  if (!options.stats_json_path.empty() &&
      !st::hostapp::write_stats_json(st::hostapp::host_stats_json(sources),
                                     options.stats_json_path)) {
    std::fprintf(stderr, "storetrack-host: cannot write '%s'\n", options.stats_json_path.c_str());
    exit_code = 1;
  }
  if (recording.had_errors()) exit_code = 1;
  return exit_code;
}
