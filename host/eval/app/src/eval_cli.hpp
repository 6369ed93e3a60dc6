// storetrack-eval command line: one subcommand per evaluation procedure (docs/evaluation.md).
#pragma once

#include <string>
#include <vector>

#include "lme_command.hpp"
#include "pendulum_command.hpp"
#include "storetrack/eval/noise_floor.hpp"
#include "storetrack/eval/type_a.hpp"

namespace storetrack::evalapp {

struct TypeAArgs {
  std::vector<std::string> marks_csv;  ///< one per repetition
  std::string survey;                  ///< reference marks in the world frame
  std::string body = "p";
  eval::TypeAOptions options;
  std::string output;  ///< result JSON
};

/// noise-floor (seed 002): one static record.
struct NoiseFloorArgs {
  std::string marks_csv;     ///< the host's --marks-csv of a static record
  std::string survey;        ///< the marks' coordinates in the world frame
  std::string rig;           ///< rig calibration (optional: rig axes, stereo angles, centroid u)
  std::string bodies = "p";  ///< --body: p, s or ps
  eval::NoiseFloorOptions options;
  std::string output;  ///< result JSON
};

struct EvalCommand {
  enum class Kind { kNone, kTypeA, kLme, kNoiseFloor, kPendulum } kind = Kind::kNone;
  TypeAArgs type_a;
  LmeArgs lme;
  NoiseFloorArgs noise_floor;
  PendulumArgs pendulum;
};

/// Returns -1 to run `command`, else the exit code (0 after --help, 2 on a bad argument).
int parse_eval_command(int argc, char** argv, EvalCommand& command);

}  // namespace storetrack::evalapp
