// storetrack-eval: evaluation procedures of the instrument (docs/evaluation.md). Subcommands:
//   type-a   repeated static marks CSVs + world survey -> Type A per mark and axis
//            (eval_commands.cpp, run_type_a)
//   lme      scale-bar marks CSVs + bar definition -> VDI/VDE 2634-1 length measuring error
//            (lme_command.cpp, run_lme)
//   noise-floor  one static marks CSV + world survey [+ rig] -> seed 002's variance and bias
//            errors, image-coordinate, stereo-angle and distance errors (noise_floor_command.cpp)
//   pendulum SisTrO dynamic calibration: pendulum runs' marks CSVs -> identified model and the
//            dynamic error per axis (pendulum_command.cpp, run_pendulum)
// Exit codes: 0 ok, 1 runtime failure (writing files), 2 bad arguments or input.
#include <iostream>

#include "eval_cli.hpp"
#include "eval_commands.hpp"
#include "noise_floor_command.hpp"

int main(int argc, char** argv) {
  namespace app = storetrack::evalapp;
  app::EvalCommand command;
  if (const int rc = app::parse_eval_command(argc, argv, command); rc >= 0) return rc;
  switch (command.kind) {
    case app::EvalCommand::Kind::kTypeA:
      return app::run_type_a(command.type_a, std::cout, std::cerr);
    case app::EvalCommand::Kind::kLme:
      return app::run_lme(command.lme, std::cout, std::cerr);
    case app::EvalCommand::Kind::kNoiseFloor:
      return app::run_noise_floor(command.noise_floor, std::cout, std::cerr);
    case app::EvalCommand::Kind::kPendulum:
      return app::run_pendulum(command.pendulum, std::cout, std::cerr);
    case app::EvalCommand::Kind::kNone:
      break;
  }
  return 2;
}
