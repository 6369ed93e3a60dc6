#include "host_options.hpp"

#include <cstdio>
#include <stdexcept>

#include "storetrack/cli/command_line.hpp"
#include "storetrack/live/live_server.hpp"

namespace storetrack::hostapp {

int parse_host_options(int argc, char** argv, HostOptions& o, InputFileCheck files) {
  cli::Command app{
      "storetrack-host: exposure alignment, 6-DoF store pose with GUM uncertainty, "
      "FTI output (iNET-X, IRIG 106 Chapter 10, CSV)"};
  HostConfig& cfg = o.cfg;
  // A recording's command line names files of the machine that recorded it: its inputs channel
  // holds their bytes (storetrack-post).
  auto input = [files](cli::Option option) {
    if (files == InputFileCheck::kExisting) option.existing_file();
  };
  input(app.option("--calibration", o.calibration_path, "Rig calibration JSON").required());
  input(app.option("--pylon-survey", o.pylon_path, "Pylon mark survey JSON").required());
  input(app.option("--store-survey", o.store_path, "Store (or pendulum board) mark survey JSON")
            .required());
  input(app.option("--config", o.config_path,
                   "Host configuration JSON (values CLI options override)"));
  input(app.option("--initial-marks", o.initial_marks_path,
                   "Initial mark positions in the world frame (installation survey), JSON"));
  app.option("--udp-port", cfg.udp_port, "UDP port to receive observations on (0: no UDP)")
      .range(0, 65535);
  app.option("--udp-bind", cfg.udp_bind,
             "Local address to bind (required with UDP; 0.0.0.0: every interface)");
  app.option("--udp-source", o.udp_sources,
             "UNIT@a.b.c.d: accept unit UNIT's datagrams from this address only (repeat)");
  app.flag("--no-udp-kernel-filter", o.no_udp_kernel_filter,
           "Check --udp-source in the host only, not also in the kernel (every datagram is read "
           "and counted by cause; a flood can then fill the socket buffer)");
  app.option("--udp-group", cfg.udp_group, "Multicast group to join");
  app.option("--udp-interface", cfg.udp_interface, "Interface address for the multicast join");
  app.option("--can", cfg.can_interfaces, "SocketCAN interface(s) to receive CAN FD on");
  app.option("--max-wait-ms", o.max_wait_ms, "Aligner: longest wait for missing cameras")
      .positive();
  app.option("--min-cameras", o.min_cameras, "Aligner: fewer cameras -> exposure dropped")
      .range(1, 32);
  app.option("--ch10", cfg.ch10_path, "IRIG 106 Chapter 10 output file");
  app.option("--ch10-sync", o.ch10_sync, "every: fdatasync each packet; none")
      .one_of({"every", "none"});
  app.option("--ch10-existing", o.ch10_existing,
             "When --ch10 exists: number (record to NAME.001.ch10, ...) or refuse (exit 2)")
      .one_of({"number", "refuse"});
  app.option("--csv", cfg.csv_path, "CSV of FTI samples");
  app.option("--marks-csv", cfg.marks_csv_path, "CSV of per-mark observations and residuals");
  app.option("--rigid-csv", cfg.rigid_csv_path, "CSV of rigid-body pair tests");
  app.option("--clearance-csv", cfg.clearance_csv_path,
             "CSV of every aircraft part's clearance per sample (needs clearance.geometry)");
  app.option("--inetx", cfg.inetx_destination, "iNET-X destination address:port");
  app.option("--inetx-stream-id", cfg.inetx_stream_id, "iNET-X stream id");
  app.option("--duration-s", o.limits.duration_s, "Stop after this long (0: until signalled)");
  app.option("--idle-exit-s", o.limits.idle_exit_s,
             "Stop when no observation arrived for this long after the first one");
  app.option("--expect-exposures", o.limits.expect_exposures,
             "Stop after this many exposures were released (0: no limit)");
  app.option("--live", o.live_address,
             "Serve the live page (read-only) on ADDR:PORT, e.g. 127.0.0.1:8080; no default "
             "address (0.0.0.0 = every interface); port 0 = any free port");
  app.option("--live-max-clients", o.live_max_clients,
             "Live page: event streams served at once (more are refused)")
      .range(1, 256);
  app.option("--stats-json", o.stats_json_path, "Write all counters as JSON at exit");
  app.flag("--progress", o.limits.progress, "Print a progress line every second (stderr)");
  app.option("--log-level", o.log_level, "trace|debug|info|warn|error")
      .one_of({"trace", "debug", "info", "warn", "error"});
  if (const int rc = app.parse(argc, argv); rc >= 0) return rc;
  // Before any input file is read: a live page without a bind address is refused at once.
  if (!o.live_address.empty()) {
    try {
      live::parse_live_address(o.live_address);
    } catch (const std::invalid_argument& e) {
      std::fprintf(stderr, "storetrack-host: %s\n", e.what());
      return 2;
    }
  }
  return -1;
}

}  // namespace storetrack::hostapp
