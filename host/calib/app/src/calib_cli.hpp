// storetrack-calib command line: one subcommand per calibration step (docs/calibration.md).
#pragma once

#include <string>
#include <vector>

#include "compare_command.hpp"
#include "dot_detect_command.hpp"
#include "register_command.hpp"
#include "storetrack/calib/charuco_detection.hpp"
#include "storetrack/calib/chessboard_detection.hpp"
#include "storetrack/calib/intrinsic_calibration.hpp"
#include "storetrack/calib/rig_calibration.hpp"
#include "triangulate_command.hpp"

namespace storetrack::calibapp {

struct DetectArgs {
  std::string board = "chessboard";
  calib::ChessboardSpec chessboard;
  calib::CharucoSpec charuco;  ///< its square_m is chessboard.square_m (one --square option)
  DotDetectArgs dots;          ///< --board dots | ring-dots (cols / rows: chessboard's)
  int camera = 0;
  std::vector<std::string> images;
  std::string output;
  std::string report_json;  ///< per-image outcome for host/report/storetrack_calib_report.py
};

struct IntrinsicArgs {
  std::string observations;
  int camera = 0;
  int unit_id = 0;
  std::string image_size;  ///< "WxH"; overrides the CSV's "# image_size" line
  calib::IntrinsicOptions options;
  std::string lens_model = "rational-brown";  ///< --lens-model (one_of: known names only)
  bool no_outlier_rejection = false;
  std::string board_deflection = "auto";  ///< on | off | auto -> options.board_deflection
  bool no_model_check = false;            ///< skip cross-validation and the residual map (speed)
  std::string output;
  std::string residuals_csv;
};

struct RigArgs {
  std::vector<std::string> observations;  ///< CSVs, merged (e.g. one per camera from detect)
  std::vector<std::string> image_sizes;   ///< "CAMERA=WxH", when a CSV has no image_size line
  int unit_id = 0;
  calib::RigOptions options;
  std::string lens_model = "rational-brown";  ///< --lens-model (one_of: known names only)
  bool no_outlier_rejection = false;
  std::string board_deflection = "auto";  ///< each camera's own (start) fit; see docs
  bool no_model_check = false;            ///< skip cross-validation and the residual map (speed)
  std::string output;
  std::string residuals_csv;
};

struct CalibCommand {
  enum class Kind {
    kNone,
    kDetect,
    kIntrinsic,
    kRig,
    kRegister,
    kCompare,
    kUncertaintyMap,
    kTriangulate
  } kind = Kind::kNone;
  DetectArgs detect;
  IntrinsicArgs intrinsic;
  RigArgs rig;
  RegisterArgs register_args;
  CompareArgs compare;
  UncertaintyMapArgs uncertainty_map;
  TriangulateArgs triangulate;
};

/// Returns -1 to run `command`, else the exit code (0 after --help, 2 on a bad argument).
int parse_calib_command(int argc, char** argv, CalibCommand& command);

}  // namespace storetrack::calibapp
