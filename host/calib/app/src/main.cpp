// storetrack-calib: camera calibration with covariance (docs/calibration.md). Subcommands:
//   detect     images -> observation CSV          (calib_commands.cpp, run_detect)
//   intrinsic  observation CSV -> calibration JSON (calib_commands.cpp, run_intrinsic)
//   rig        observation CSVs -> calibration JSON of all cameras (calib_commands.cpp, run_rig)
//   register   rig JSON + world survey + marks CSV -> registered JSON (register_command.cpp)
//   compare, uncertainty-map   rig JSON(s) -> result JSON (compare_command.cpp)
//   triangulate  rig JSON + pixel observations CSV -> marks CSV (triangulate_command.cpp)
// Exit codes: 0 ok, 1 runtime failure (writing files), 2 bad arguments or input.
#include <iostream>

#include "calib_cli.hpp"
#include "calib_commands.hpp"

int main(int argc, char** argv) {
  namespace app = storetrack::calibapp;
  app::CalibCommand command;
  if (const int rc = app::parse_calib_command(argc, argv, command); rc >= 0) return rc;
  switch (command.kind) {
    case app::CalibCommand::Kind::kDetect:
      return app::run_detect(command.detect, std::cout, std::cerr);
    case app::CalibCommand::Kind::kIntrinsic:
      return app::run_intrinsic(command.intrinsic, std::cout, std::cerr);
    case app::CalibCommand::Kind::kRig:
      return app::run_rig(command.rig, std::cout, std::cerr);
    case app::CalibCommand::Kind::kRegister:
      return app::run_register(command.register_args, std::cout, std::cerr);
    case app::CalibCommand::Kind::kCompare:
      return app::run_compare(command.compare, std::cout, std::cerr);
    case app::CalibCommand::Kind::kUncertaintyMap:
      return app::run_uncertainty_map(command.uncertainty_map, std::cout, std::cerr);
    case app::CalibCommand::Kind::kTriangulate:
      return app::run_triangulate(command.triangulate, std::cout, std::cerr);
    case app::CalibCommand::Kind::kNone:
      break;
  }
  return 2;
}
