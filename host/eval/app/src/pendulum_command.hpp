// storetrack-eval pendulum: SisTrO's dynamic calibration (docs/evaluation.md, "Pendulum").
#pragma once

#include <ostream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include "storetrack/cli/command_line.hpp"
#include "storetrack/eval/pendulum.hpp"

namespace storetrack::evalapp {

struct PendulumArgs {
  std::vector<std::string> marks_csv;  ///< one per run (release)
  std::string body = "s";
  double l1_m = 0, l1_sigma_m = 0;  ///< 0: not given
  std::string covariance = "observed";
  std::string calibration;  ///< rig calibration: the reference camera's optical axis
  int axis_camera = -1;     ///< camera id of the reference camera (-1: the first)
  std::vector<double> down_w = {0, 0, 1};
  eval::PendulumOptions options;
  std::string output;  ///< result JSON
};

void add_pendulum_command(cli::Command& app, PendulumArgs& args);
/// Copies the parsed strings into args.options.
void finish_pendulum_args(PendulumArgs& args);

/// 0 ok, 1 the result file could not be written, 2 bad input (message on `err`).
int run_pendulum(PendulumArgs args, std::ostream& out, std::ostream& err);

nlohmann::json pendulum_json(const eval::PendulumResult& r, const PendulumArgs& args);

}  // namespace storetrack::evalapp
