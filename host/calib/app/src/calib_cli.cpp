#include "calib_cli.hpp"

#include <CLI/CLI.hpp>

namespace storetrack::calibapp {
namespace {

void add_detect(CLI::App& app, DetectArgs& a) {
  CLI::App* sub = app.add_subcommand("detect", "Board observations from images -> CSV");
  sub->add_option("--board", a.board, "Board type")->check(CLI::IsMember({"chessboard"}));
  sub->add_option("--cols", a.chessboard.cols, "Inner corners per board row")
      ->check(CLI::Range(2, 1000));
  sub->add_option("--rows", a.chessboard.rows, "Inner corners per board column")
      ->check(CLI::Range(2, 1000));
  sub->add_option("--square", a.chessboard.square_m, "Square side [m]")->check(CLI::PositiveNumber);
  sub->add_option("--camera", a.camera, "Camera id written to the CSV")->check(CLI::Range(0, 255));
  sub->add_option("images", a.images, "Images (frame = position in this list)")->required();
  sub->add_option("-o,--output", a.output, "Observation CSV to write")->required();
}

/// The model flags and outlier gate, shared by intrinsic and rig.
void add_model_options(CLI::App* sub, calib::IntrinsicOptions& o, bool& no_outlier_rejection) {
  sub->add_flag("--fix-aspect-ratio", o.fix_aspect_ratio, "fx = aspect * fy (OpenCV's flag)");
  sub->add_option("--aspect-ratio", o.aspect_ratio, "fx / fy with --fix-aspect-ratio")
      ->check(CLI::PositiveNumber);
  sub->add_flag("--fix-principal-point", o.fix_principal_point, "cx, cy at the image centre");
  sub->add_flag("--zero-tangential", o.zero_tangential, "p1 = p2 = 0");
  sub->add_flag("--fix-k1", o.fix_k1, "k1 = 0");
  sub->add_flag("--fix-k2", o.fix_k2, "k2 = 0");
  sub->add_flag("--fix-k3", o.fix_k3, "k3 = 0");
  sub->add_flag("--rational", o.rational, "Estimate k4, k5, k6 (rational model)");
  sub->add_option("--outlier-false-alarm", o.outlier_false_alarm,
                  "Probability of rejecting any point of a clean set")
      ->check(CLI::Range(0.0, 0.5));
  sub->add_flag("--no-outlier-rejection", no_outlier_rejection, "Keep every point");
  sub->add_option("--min-views", o.min_views, "Fewest board poses accepted (per camera)")
      ->check(CLI::Range(2, 100000));
}

void add_intrinsic(CLI::App& app, IntrinsicArgs& a) {
  CLI::App* sub = app.add_subcommand("intrinsic", "One camera's intrinsics with covariance");
  sub->add_option("observations", a.observations, "Observation CSV")
      ->required()
      ->check(CLI::ExistingFile);
  sub->add_option("--camera", a.camera, "Camera to calibrate")->check(CLI::Range(0, 255));
  sub->add_option("--unit", a.unit_id, "Unit id written to the calibration file")
      ->check(CLI::Range(0, 255));
  sub->add_option("--image-size", a.image_size, "WxH, when the CSV has no image_size line");
  add_model_options(sub, a.options, a.no_outlier_rejection);
  sub->add_option("-o,--output", a.output, "Rig calibration JSON to write")->required();
  sub->add_option("--residuals", a.residuals_csv, "Per-point residual CSV to write");
}

void add_rig(CLI::App& app, RigArgs& a) {
  CLI::App* sub = app.add_subcommand(
      "rig", "All cameras jointly (bundle adjustment, camera 0 = reference) with covariance");
  sub->add_option("observations", a.observations, "Observation CSVs (merged)")
      ->required()
      ->check(CLI::ExistingFile);
  sub->add_option("--unit", a.unit_id, "Unit id written to the calibration file")
      ->check(CLI::Range(0, 255));
  sub->add_option("--image-size", a.image_sizes,
                  "CAMERA=WxH, when a CSV has no image_size line (repeatable)");
  add_model_options(sub, a.options.intrinsic, a.no_outlier_rejection);
  sub->add_option("--min-common-views", a.options.min_common_views,
                  "Fewest frames two cameras must share to be linked")
      ->check(CLI::Range(1, 100000));
  sub->add_option("-o,--output", a.output, "Rig calibration JSON to write")->required();
  sub->add_option("--residuals", a.residuals_csv, "Per-point residual CSV to write");
}

}  // namespace

int parse_calib_command(int argc, char** argv, CalibCommand& command) {
  CLI::App app{"storetrack-calib: camera calibration with covariance (docs/calibration.md)"};
  app.require_subcommand(1);
  add_detect(app, command.detect);
  add_intrinsic(app, command.intrinsic);
  add_rig(app, command.rig);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? 0 : 2;
  }
  if (app.got_subcommand("detect")) command.kind = CalibCommand::Kind::kDetect;
  if (app.got_subcommand("intrinsic")) {
    command.kind = CalibCommand::Kind::kIntrinsic;
    if (command.intrinsic.no_outlier_rejection) command.intrinsic.options.outlier_false_alarm = 0;
  }
  if (app.got_subcommand("rig")) {
    command.kind = CalibCommand::Kind::kRig;
    if (command.rig.no_outlier_rejection) command.rig.options.intrinsic.outlier_false_alarm = 0;
  }
  return -1;
}

}  // namespace storetrack::calibapp
