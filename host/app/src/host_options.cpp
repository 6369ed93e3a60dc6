#include "host_options.hpp"

#include <CLI/CLI.hpp>

namespace storetrack::hostapp {

int parse_host_options(int argc, char** argv, HostOptions& o) {
  CLI::App app{
      "storetrack-host: exposure alignment, 6-DoF store pose with GUM uncertainty, "
      "FTI output (iNET-X, IRIG 106 Chapter 10, CSV)"};
  HostConfig& cfg = o.cfg;
  app.add_option("--calibration", o.calibration_path, "Rig calibration JSON")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--pylon-survey", o.pylon_path, "Pylon mark survey JSON")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--store-survey", o.store_path, "Store (or pendulum board) mark survey JSON")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--config", o.config_path, "Host configuration JSON (values CLI options override)")
      ->check(CLI::ExistingFile);
  app.add_option("--initial-marks", o.initial_marks_path,
                 "Initial mark positions in the world frame (installation survey), JSON")
      ->check(CLI::ExistingFile);
  app.add_option("--udp-port", cfg.udp_port, "UDP port to receive observations on (0: no UDP)")
      ->check(CLI::Range(0, 65535));
  app.add_option("--udp-bind", cfg.udp_bind,
                 "Local address to bind (required with UDP; 0.0.0.0: every interface)");
  app.add_option("--udp-source", o.udp_sources,
                 "UNIT@a.b.c.d: accept unit UNIT's datagrams from this address only (repeat)");
  app.add_option("--udp-group", cfg.udp_group, "Multicast group to join");
  app.add_option("--udp-interface", cfg.udp_interface, "Interface address for the multicast join");
  app.add_option("--can", cfg.can_interfaces, "SocketCAN interface(s) to receive CAN FD on");
  app.add_option("--max-wait-ms", o.max_wait_ms, "Aligner: longest wait for missing cameras")
      ->check(CLI::PositiveNumber);
  app.add_option("--min-cameras", o.min_cameras, "Aligner: fewer cameras -> exposure dropped")
      ->check(CLI::Range(1, 32));
  app.add_option("--ch10", cfg.ch10_path, "IRIG 106 Chapter 10 output file");
  app.add_option("--ch10-sync", o.ch10_sync, "every: fdatasync each packet; none")
      ->check(CLI::IsMember({"every", "none"}));
  app.add_option("--ch10-existing", o.ch10_existing,
                 "When --ch10 exists: number (record to NAME.001.ch10, ...) or refuse (exit 2)")
      ->check(CLI::IsMember({"number", "refuse"}));
  app.add_option("--csv", cfg.csv_path, "CSV of FTI samples");
  app.add_option("--marks-csv", cfg.marks_csv_path, "CSV of per-mark observations and residuals");
  app.add_option("--rigid-csv", cfg.rigid_csv_path, "CSV of rigid-body pair tests");
  app.add_option("--inetx", cfg.inetx_destination, "iNET-X destination address:port");
  app.add_option("--inetx-stream-id", cfg.inetx_stream_id, "iNET-X stream id");
  app.add_option("--duration-s", o.limits.duration_s, "Stop after this long (0: until signalled)");
  app.add_option("--idle-exit-s", o.limits.idle_exit_s,
                 "Stop when no observation arrived for this long after the first one");
  app.add_option("--expect-exposures", o.limits.expect_exposures,
                 "Stop after this many exposures were released (0: no limit)");
  app.add_option("--stats-json", o.stats_json_path, "Write all counters as JSON at exit");
  app.add_flag("--progress", o.limits.progress, "Print a progress line every second (stderr)");
  app.add_option("--log-level", o.log_level, "trace|debug|info|warn|error")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error"}));
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? 0 : 2;
  }
  return -1;
}

}  // namespace storetrack::hostapp
