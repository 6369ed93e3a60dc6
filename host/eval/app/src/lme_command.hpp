// storetrack-eval lme: VDI/VDE 2634-1 length measuring error of calibrated scale bars
// (docs/evaluation.md): its arguments, command line, run and result JSON.
#pragma once

#include <ostream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include "storetrack/cli/command_line.hpp"
#include "storetrack/eval/length_measuring_error.hpp"

namespace storetrack::evalapp {

struct LmeArgs {
  std::vector<std::string> marks_csv;  ///< one per repetition
  std::string bars;                    ///< scale-bar definition (common/survey scale_bars.hpp)
  std::string rig;                     ///< rig calibration the host used (optional)
  double mpe_a_m = 0, mpe_k = 0, mpe_m = 0;
  eval::LmeOptions options;
  std::string output;               ///< result JSON
  cli::Command* command = nullptr;  ///< the subcommand, to see which MPE options were given
};

/// Adds the "lme" subcommand to `app`.
void add_lme_command(cli::Command& app, LmeArgs& args);
/// After parsing: the MPE from --mpe-a/--mpe-k or --mpe; -1 ok, else 2 (message on `err`).
int finish_lme_args(LmeArgs& args, std::ostream& err);
/// 0 ok, 1 the result file could not be written, 2 bad input (message on `err`).
int run_lme(const LmeArgs& args, std::ostream& out, std::ostream& err);
/// The machine-readable result (docs/evaluation.md, "Result JSON").
nlohmann::json lme_json(const eval::LmeResult& r, const LmeArgs& args);

}  // namespace storetrack::evalapp
