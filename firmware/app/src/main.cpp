// storetrack-unit: one camera unit (docs/unit-config.md).
//
//   storetrack-unit run      [--config FILE] [overrides...]   capture, centroid, send
//   storetrack-unit snapshot [--config FILE] [overrides...] --out STEM [--skip N]
//   storetrack-unit modbus-doc                                 docs/modbus.md from the table
//   storetrack-unit print-config [--config FILE] [overrides...]
//
// Exit codes: 0 ok, 1 runtime error, 2 usage/configuration error, 3 start failure.
#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>
#include "storetrack/cli/command_line.hpp"

#include "snapshot.hpp"
#include "storetrack/health/register_map.hpp"
#include "unit_config.hpp"
#include "unit_runner.hpp"

namespace {

using namespace storetrack;
using namespace storetrack::unit;
namespace cli = storetrack::cli;

std::atomic<bool> g_stop{false};

void on_signal(int) {
  g_stop.store(true);
}

struct Overrides {
  std::string config_file;
  std::string source, scenario, replay_dir, device, trigger, gpio_chip, clock_state;
  int camera_index = 0, width = 0, height = 0, input = 0, gpio_line = 0, unit_id = 0, camera_id = 0,
      threshold = 0, latency_ns = 0;
  std::vector<int> roi;
  std::uint64_t seed = 1;
  std::vector<unsigned> gpio_lines;
  double rate_hz = 0, pulse_width_us = 0, duration_s = 0, replay_rate = 0;
  long frames = 0;
  int start_exposure = 0;
  double sim_pace_hz = 0;
  int sim_background_pool = -1;
  std::int64_t sim_pace_origin = 0;
  std::vector<std::int64_t> tai_step;
  std::vector<std::string> udp, can;
  std::string modbus, stats_json, edges_csv;
  std::string ptp4l_uds, ptp4l_client_dir;
  std::int64_t ptp4l_lock_threshold_ns = 0;
  double ptp4l_holdover_s = 0;
  bool ptp4l_measure_only = false;
  bool keep_numbering = false;
  bool realtime = false, no_links = false, no_modbus = false, maintenance = false, verbose = false,
       replay_loop = false, triggered_only = false;
};

void add_common(cli::Command* app, Overrides& o) {
  app->option("-c,--config", o.config_file, "JSON configuration file (docs/unit-config.md)");
  app->option("--source", o.source, "Frame source: sim | replay | v4l2 | none (trigger only)");
  app->option("--scenario", o.scenario, "sim: scenario JSON file");
  app->option("--camera-index", o.camera_index, "sim: camera index in the scenario");
  app->option("--seed", o.seed, "sim: random seed");
  app->flag("--realtime", o.realtime, "sim: pace frames at the scenario frame rate");
  app->option("--sim-start-exposure", o.start_exposure,
              "sim fault: start at this exposure, trigger numbering from 0 (a restarted unit)")
      .non_negative();
  app->flag("--sim-keep-numbering", o.keep_numbering,
            "sim fault: with --sim-start-exposure, keep the rig's trigger numbering (not from 0)");
  app->option("--sim-pace-hz", o.sim_pace_hz,
              "sim: with --realtime, pace at this rate instead of the scenario's (slow motion)")
      .positive();
  app->option("--sim-pace-origin-mono-ns", o.sim_pace_origin,
              "sim: with --realtime, exposure 0 is due at this CLOCK_MONOTONIC time [ns] (one "
              "schedule for the units of a run, restarted ones too; default: the unit's start)")
      .positive();
  app->option("--sim-background-pool", o.sim_background_pool,
              "sim: render N backgrounds at start and only the spots per exposure (default 8 "
              "with --realtime at the scenario's rate, where whole frames are too slow to "
              "render; 0: whole frames)")
      .range(0, 64);
  app->option("--sim-tai-step", o.tai_step,
              "sim fault: FROM,TO,NS: TAI clock off by NS for exposures [FROM, TO)")
      .delimiter(',')
      .expected(3);
  app->option("--replay-dir", o.replay_dir, "replay: directory of PGM frames + triggers.csv");
  app->option("--replay-rate", o.replay_rate, "replay: frames per second (0: as fast as possible)");
  app->flag("--replay-loop", o.replay_loop, "replay: start again at the end");
  app->option("--device", o.device, "v4l2: device node, e.g. /dev/video0");
  app->option("--width", o.width, "v4l2: requested width [px]");
  app->option("--height", o.height, "v4l2: requested height [px]");
  app->option("--input", o.input, "v4l2: VIDIOC_S_INPUT index (vivid loopback: 2)");
  app->option("--trigger", o.trigger, "Trigger: none | sim | gpio-master | gpio-slave");
  app->option("--gpio-chip", o.gpio_chip, "GPIO chip (path, name or label)");
  app->option("--gpio-lines", o.gpio_lines, "gpio-master: output line offsets").delimiter(',');
  app->option("--gpio-line", o.gpio_line, "gpio-slave: input line offset");
  app->option("--rate-hz", o.rate_hz, "Trigger rate [Hz] (master: generated; slave: expected)");
  app->option("--pulse-width-us", o.pulse_width_us, "gpio-master: pulse width [us]");
  app->option("--latency-ns", o.latency_ns, "Expected frame time stamp - trigger edge [ns]");
  app->option("--edges-csv", o.edges_csv, "Write every trigger edge to this CSV file");
  app->flag("--triggered-only", o.triggered_only,
            "Send only frames a trigger edge claims; frames without marks claim none "
            "(free-running source standing in for a triggered camera)");
  app->option("--unit-id", o.unit_id, "Unit id in messages (0..254)");
  app->option("--camera-id", o.camera_id, "Camera id in messages (0..254)");
  app->option("--threshold-dn", o.threshold, "Centroid threshold above background (0: auto)");
  app->option("--roi", o.roi, "Search region x y width height [px]").expected(4);
  app->option("--clock-state", o.clock_state,
              "auto | free-running | locking | locked | holdover | ptp4l (measured)");
  app->option("--ptp4l-uds", o.ptp4l_uds, "clock ptp4l: ptp4l's uds_address (/var/run/ptp4l)");
  app->option("--ptp4l-client-dir", o.ptp4l_client_dir,
              "clock ptp4l: directory for this unit's own socket (/run/storetrack)");
  app->option("--ptp4l-lock-threshold-ns", o.ptp4l_lock_threshold_ns,
              "clock ptp4l: |offset from master| for LOCKED [ns]");
  app->option("--ptp4l-holdover-s", o.ptp4l_holdover_s,
              "clock ptp4l: HOLDOVER lasts at most this long after the master is lost [s]");
  app->flag("--ptp4l-measure-only", o.ptp4l_measure_only,
            "clock ptp4l: ptp4l runs free_running (its port stays UNCALIBRATED): lock on the "
            "measured offset alone");
  app->option("--udp", o.udp, "UDP destination address:port (repeatable; replaces config)");
  app->option("--can", o.can, "CAN FD interface (repeatable; replaces config)");
  app->flag("--no-links", o.no_links, "Send nothing (bench, benchmarks)");
  app->option("--modbus", o.modbus, "Modbus TCP listen address:port");
  app->flag("--no-modbus", o.no_modbus, "Do not start the Modbus server");
  app->flag("--maintenance", o.maintenance, "Allow Modbus configuration writes");
  app->option("--frames", o.frames, "Stop after N frames (source none: N edges); 0 = no limit");
  app->option("--duration-s", o.duration_s, "Stop after this many seconds; 0 = no limit");
  app->option("--stats-json", o.stats_json, "Write run statistics as JSON here at exit");
  app->flag("-v,--verbose", o.verbose, "Print notes and health to stderr");
}

bool given(cli::Command* app, const char* name) {
  return app->given(name);
}

UnitConfig build_config(cli::Command* app, const Overrides& o) {
  UnitConfig c;
  c.unit_id = -1;  // "from the scenario" for the simulator, else 0
  c.camera_id = -1;
  if (!o.config_file.empty()) load_config_file(o.config_file, c);
  if (given(app, "--source")) c.source = parse_source(o.source);
  if (given(app, "--scenario")) c.sim.scenario = o.scenario;
  if (given(app, "--camera-index")) c.sim.camera_index = o.camera_index;
  if (given(app, "--seed")) c.sim.seed = o.seed;
  if (o.realtime) c.sim.realtime = true;
  if (given(app, "--sim-start-exposure")) c.sim.start_exposure = o.start_exposure;
  if (o.keep_numbering) c.sim.keep_numbering = true;
  if (given(app, "--sim-pace-hz")) c.sim.pace_hz = o.sim_pace_hz;
  if (given(app, "--sim-background-pool")) c.sim.background_pool = o.sim_background_pool;
  if (given(app, "--sim-pace-origin-mono-ns")) c.sim.pace_origin_mono_ns = o.sim_pace_origin;
  if (o.tai_step.size() == 3) {
    if (o.tai_step[0] < 0 || o.tai_step[1] <= o.tai_step[0] || o.tai_step[1] > (1 << 30))
      throw ConfigError("--sim-tai-step: need 0 <= FROM < TO (exposure indices)");
    c.sim.tai_step_from = static_cast<int>(o.tai_step[0]);
    c.sim.tai_step_to = static_cast<int>(o.tai_step[1]);
    c.sim.tai_step_ns = o.tai_step[2];
  }
  if (given(app, "--replay-dir")) c.replay.directory = o.replay_dir;
  if (given(app, "--replay-rate")) c.replay.rate_hz = o.replay_rate;
  if (o.replay_loop) c.replay.loop = true;
  if (given(app, "--device")) c.v4l2.device.device = o.device;
  if (given(app, "--width")) c.v4l2.device.width = o.width;
  if (given(app, "--height")) c.v4l2.device.height = o.height;
  if (given(app, "--input")) c.v4l2.device.input = o.input;
  if (given(app, "--trigger")) c.trigger.mode = parse_trigger_mode(o.trigger);
  if (given(app, "--gpio-chip")) c.trigger.chip = o.gpio_chip;
  if (given(app, "--gpio-lines")) c.trigger.lines = o.gpio_lines;
  if (given(app, "--gpio-line")) c.trigger.line = static_cast<unsigned>(o.gpio_line);
  if (given(app, "--rate-hz")) c.trigger.rate_hz = o.rate_hz;
  if (given(app, "--pulse-width-us")) {
    c.trigger.pulse_width_ns = static_cast<std::int64_t>(o.pulse_width_us * 1000);
  }
  if (given(app, "--latency-ns")) c.trigger.latency_ns = o.latency_ns;
  if (given(app, "--edges-csv")) c.trigger.edges_csv = o.edges_csv;
  if (o.triggered_only) c.trigger.triggered_only = true;
  if (given(app, "--unit-id")) c.unit_id = o.unit_id;
  if (given(app, "--camera-id")) c.camera_id = o.camera_id;
  if (given(app, "--threshold-dn")) c.centroid.threshold_dn = o.threshold;
  if (given(app, "--roi") && o.roi.size() == 4) {
    c.roi_x = o.roi[0];
    c.roi_y = o.roi[1];
    c.roi_width = o.roi[2];
    c.roi_height = o.roi[3];
  }
  if (given(app, "--clock-state")) c.clock_state = o.clock_state;
  if (given(app, "--ptp4l-uds")) c.ptp4l.ptp4l.uds_path = o.ptp4l_uds;
  if (given(app, "--ptp4l-client-dir")) c.ptp4l.ptp4l.client_dir = o.ptp4l_client_dir;
  if (given(app, "--ptp4l-lock-threshold-ns"))
    c.ptp4l.lock.lock_threshold_ns = o.ptp4l_lock_threshold_ns;
  if (given(app, "--ptp4l-holdover-s")) {
    if (!(o.ptp4l_holdover_s >= 0 && o.ptp4l_holdover_s <= 3600))
      throw ConfigError("--ptp4l-holdover-s must be in [0, 3600]");
    c.ptp4l.lock.holdover_ns = static_cast<std::int64_t>(o.ptp4l_holdover_s * 1e9);
  }
  if (o.ptp4l_measure_only) c.ptp4l.lock.measure_only = true;
  if (given(app, "--udp")) {
    c.udp.clear();
    for (const auto& d : o.udp) {
      link::UdpLinkConfig u;
      u.destination = d;
      c.udp.push_back(u);
    }
  }
  if (given(app, "--can")) {
    c.canfd.clear();
    for (const auto& i : o.can) {
      link::CanFdLinkConfig l;
      l.interface = i;
      c.canfd.push_back(l);
    }
  }
  if (o.no_links) {
    c.udp.clear();
    c.canfd.clear();
  }
  if (given(app, "--modbus")) {
    const auto colon = o.modbus.rfind(':');
    if (colon == std::string::npos) throw ConfigError("--modbus needs address:port");
    c.modbus_address = o.modbus.substr(0, colon);
    try {
      c.modbus_port = std::stoi(o.modbus.substr(colon + 1));
    } catch (const std::exception&) {
      throw ConfigError("--modbus: bad port in '" + o.modbus + "'");
    }
  }
  if (o.no_modbus) c.modbus_enabled = false;
  if (o.maintenance) c.maintenance = true;
  if (given(app, "--frames")) c.frames = o.frames;
  if (given(app, "--duration-s")) c.duration_s = o.duration_s;
  if (given(app, "--stats-json")) c.stats_json = o.stats_json;
  if (o.verbose) c.verbose = true;
  UnitConfig checked = c;
  if (checked.unit_id < 0) checked.unit_id = 0;
  if (checked.camera_id < 0) checked.camera_id = 0;
  validate(checked);
  return c;
}

void install_signals() {
  struct sigaction sa {};
  sa.sa_handler = on_signal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
  std::signal(SIGPIPE, SIG_IGN);
}

int write_stats(const UnitRunner& runner, const std::string& path, const std::string& reason,
                int code) {
  if (path.empty()) return 0;
  std::ofstream out(path);
  out << runner.stats_json(reason, code);
  if (!out) {
    std::fprintf(stderr, "storetrack-unit: cannot write %s\n", path.c_str());
    return -1;
  }
  return 0;
}

int do_run(cli::Command* cmd, const Overrides& o) {
  UnitConfig config;
  try {
    config = build_config(cmd, o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-unit: configuration: %s\n", e.what());
    return kExitUsage;
  }
  install_signals();
  UnitRunner runner(config, simulator_camera_factory());
  std::string error;
  const int setup = runner.setup(error);
  if (setup != kExitOk) {
    std::fprintf(stderr, "storetrack-unit: %s\n", error.c_str());
    write_stats(runner, config.stats_json, error, setup);
    return setup;
  }
  if (config.verbose && !runner.notes().empty()) std::fputs(runner.notes().c_str(), stderr);
  const int code = runner.run(g_stop);
  const std::string reason = g_stop.load()                   ? "signal"
                             : code == kExitOk               ? "done"
                             : !runner.stop_reason().empty() ? runner.stop_reason()
                                                             : "runtime error";
  if (!runner.stop_reason().empty()) std::fprintf(stderr, "storetrack-unit: %s\n", reason.c_str());
  if (const std::string verdict = runner.realtime_verdict(); !verdict.empty())
    std::fprintf(stderr, "storetrack-unit: %s\n", verdict.c_str());
  runner.shutdown();
  if (write_stats(runner, config.stats_json, reason, code) < 0 && code == kExitOk) {
    return kExitRuntimeError;
  }
  if (config.verbose) std::fputs(runner.stats_json(reason, code).c_str(), stderr);
  return code;
}

int do_snapshot(cli::Command* cmd, const Overrides& o, const std::string& out_stem, int skip) {
  UnitConfig config;
  try {
    config = build_config(cmd, o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-unit: configuration: %s\n", e.what());
    return kExitUsage;
  }
  config.modbus_enabled = false;
  config.udp.clear();
  config.canfd.clear();
  if (config.source == SourceType::kNone) {
    std::fprintf(stderr, "storetrack-unit: snapshot needs a frame source\n");
    return kExitUsage;
  }
  config.trigger.mode = TriggerMode::kNone;
  UnitRunner runner(config, simulator_camera_factory());
  std::string error;
  if (const int rc = runner.setup(error); rc != kExitOk) {
    std::fprintf(stderr, "storetrack-unit: %s\n", error.c_str());
    return rc;
  }
  frame::FrameView frame;
  std::span<const centroid::Blob> blobs;
  if (const int rc = runner.grab(skip, frame, blobs); rc < 0) {
    std::fprintf(stderr, "storetrack-unit: snapshot: no frame (%s)\n", std::strerror(-rc));
    return kExitRuntimeError;
  }
  const std::string path = write_overlay(out_stem, frame, blobs, &error);
  if (path.empty()) {
    std::fprintf(stderr, "storetrack-unit: %s\n", error.c_str());
    return kExitRuntimeError;
  }
  std::printf("overlay: %s\n", path.c_str());
  print_mark_table(stdout, frame, blobs, runner.centroid_config());
  const std::string table = out_stem + ".txt";
  if (std::FILE* fp = std::fopen(table.c_str(), "w")) {
    print_mark_table(fp, frame, blobs, runner.centroid_config());
    std::fclose(fp);
  }
  return kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  storetrack::cli::Command app{
      "storetrack-unit: camera unit (trigger, capture, centroid, CAN FD / UDP, Modbus)"};
  app.require_subcommand(1);
  Overrides run_o, snap_o, print_o;
  cli::Command* run = &app.subcommand("run", "Capture, centroid and stream observations");
  add_common(run, run_o);
  cli::Command* snap = &app.subcommand("snapshot", "Bench aid: one frame with marks overlaid");
  add_common(snap, snap_o);
  std::string out_stem = "snapshot";
  int skip = 0;
  snap->option("-o,--out", out_stem, "Output path without extension (.png/.pgm and .txt)");
  snap->option("--skip", skip, "Frames to skip before the snapshot");
  cli::Command* doc = &app.subcommand("modbus-doc", "Print docs/modbus.md from the register table");
  cli::Command* print =
      &app.subcommand("print-config", "Print the effective configuration as JSON");
  add_common(print, print_o);
  if (const int rc = app.parse(argc, argv); rc >= 0) return rc == 0 ? kExitOk : kExitUsage;
  if (doc->parsed()) {
    std::fputs(health::render_register_map_markdown().c_str(), stdout);
    return kExitOk;
  }
  if (print->parsed()) {
    try {
      std::fputs(to_json(build_config(print, print_o)).c_str(), stdout);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "storetrack-unit: configuration: %s\n", e.what());
      return kExitUsage;
    }
    return kExitOk;
  }
  if (snap->parsed()) return do_snapshot(snap, snap_o, out_stem, skip);
  return do_run(run, run_o);
}
