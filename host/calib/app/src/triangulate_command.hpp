// storetrack-calib triangulate: pixel observations + rig calibration -> marks CSV with full
// covariance (docs/calibration.md, "Triangulate").
#pragma once

#include <ostream>
#include <string>

#include "storetrack/cli/command_line.hpp"

namespace storetrack::calibapp {

struct TriangulateArgs {
  std::string calibration, observations, output;
  std::string body = "?";  ///< the marks CSV's body column (p, s or ?)
};

void add_triangulate(cli::Command& app, TriangulateArgs& args);

/// 0 ok; 2 on bad input (a camera the calibration lacks, a malformed row, an existing output
/// file: nothing written); 1 when writing fails.
int run_triangulate(const TriangulateArgs& args, std::ostream& out, std::ostream& err);

}  // namespace storetrack::calibapp
