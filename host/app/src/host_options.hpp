// storetrack-host's command line: the input files, HostConfig overrides and the run limits.
#pragma once

#include <string>
#include <vector>

#include "host_config.hpp"
#include "host_loop.hpp"

namespace storetrack::hostapp {

struct HostOptions {
  HostConfig cfg;
  std::string calibration_path, pylon_path, store_path, config_path, initial_marks_path;
  std::string stats_json_path, ch10_sync = "every", ch10_existing = "number", log_level = "info";
  std::vector<std::string> udp_sources;  // UNIT@a.b.c.d, parsed by load_inputs
  bool no_udp_kernel_filter = false;
  double max_wait_ms = 0;
  int min_cameras = 0;
  LoopLimits limits;
  std::string live_address;  ///< --live ADDR:PORT: the live page (host/live); empty: off
  int live_max_clients = 24;
  std::vector<std::string> command_line;  // argv as given: recorded with the inputs
};

/// kExisting: the input files must exist (the host); kNone: a recorded command line
/// (storetrack-post reads the files' bytes from the recording).
enum class InputFileCheck { kExisting, kNone };

/// Parses argv into `o`; returns -1 to go on, else the exit code (0 for --help, 2 for an error).
int parse_host_options(int argc, char** argv, HostOptions& o,
                       InputFileCheck files = InputFileCheck::kExisting);

}  // namespace storetrack::hostapp
