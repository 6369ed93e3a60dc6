// storetrack-calib detect, the ChArUco board and the detect report data: the per-image outcome
// (used with its corner count, or rejected with the reason), the rejected corners and every
// detected point, for host/report/storetrack_calib_report.py (docs/calibration.md, "Reports").
#pragma once

#include <ostream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "calib_cli.hpp"
#include "storetrack/calib/charuco_detection.hpp"
#include "storetrack/cli/command_line.hpp"

namespace storetrack::calibapp {

void add_charuco_options(cli::Command& detect, calib::CharucoSpec& spec);

/// `detect --board charuco`: exit 0, 1 (a file not written) or 2 (bad board description, or
/// no image gave corners: nothing written).
int run_detect_charuco(const DetectArgs& args, std::ostream& out, std::ostream& err);

/// The report data of a detect run (format "storetrack-calib-detect").
nlohmann::json detect_report_json(const DetectArgs& args, const calib::DetectionResult& result,
                                  const std::vector<calib::RejectedCorner>& rejected_corners);

/// Writes detect_report_json to args.report_json when given; throws std::runtime_error.
void write_detect_report(const DetectArgs& args, const calib::DetectionResult& result,
                         const std::vector<calib::RejectedCorner>& rejected_corners);

}  // namespace storetrack::calibapp
