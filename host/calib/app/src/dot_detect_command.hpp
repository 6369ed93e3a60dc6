// storetrack-calib detect --board dots | ring-dots: dot grids measured with the unit's
// centroider (docs/calibration.md, "Dot grids"). The options add to the detect subcommand.
#pragma once

#include <ostream>

#include "storetrack/calib/dot_grid_detection.hpp"
#include "storetrack/cli/command_line.hpp"

namespace storetrack::calibapp {

struct DetectArgs;

struct DotDetectArgs {
  calib::DotGridSpec grid;
  calib::DotCentroidOptions centroid;
  bool light_dots = false;  ///< white / retro-reflective dots on a dark ground
};

void add_dot_detect_options(cli::Command& detect, DotDetectArgs& args);
/// Runs detect for a dot board (args.board is "dots" or "ring-dots"); cols / rows from the
/// shared --cols / --rows.
int run_dot_detect(const DetectArgs& args, std::ostream& out, std::ostream& err);

}  // namespace storetrack::calibapp
