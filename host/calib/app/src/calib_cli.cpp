#include "calib_cli.hpp"

#include "detect_report.hpp"
#include "storetrack/cli/command_line.hpp"

namespace storetrack::calibapp {
namespace {

void add_detect(cli::Command& app, DetectArgs& a) {
  cli::Command& sub = app.subcommand("detect", "Board observations from images -> CSV");
  sub.option("--board", a.board, "Board type")
      .one_of({"chessboard", "charuco", "dots", "ring-dots"});
  sub.option("--cols", a.chessboard.cols, "Chessboard, dots: inner corners / dots per board row")
      .range(2, 1000);
  sub.option("--rows", a.chessboard.rows, "Chessboard, dots: inner corners / dots per board column")
      .range(2, 1000);
  sub.option("--square", a.chessboard.square_m, "Square side [m]").positive();
  add_charuco_options(sub, a.charuco);
  sub.option("--camera", a.camera, "Camera id written to the CSV").range(0, 255);
  sub.option("images", a.images, "Images (frame = position in this list)").required();
  sub.option("-o,--output", a.output, "Observation CSV to write").required();
  sub.option("--report-json", a.report_json,
             "Per-image outcome JSON for host/report/storetrack_calib_report.py");
  add_dot_detect_options(sub, a.dots);
}

/// The model flags and outlier gate, shared by intrinsic and rig.
void add_model_options(cli::Command& sub, calib::IntrinsicOptions& o, std::string& lens_model,
                       bool& no_outlier_rejection, std::string& board_deflection) {
  sub.flag("--fix-aspect-ratio", o.fix_aspect_ratio, "fx = aspect * fy (OpenCV's flag)");
  sub.option("--aspect-ratio", o.aspect_ratio, "fx / fy with --fix-aspect-ratio").positive();
  sub.flag("--fix-principal-point", o.fix_principal_point, "cx, cy at the image centre");
  sub.flag("--zero-tangential", o.zero_tangential, "p1 = p2 = 0");
  sub.flag("--fix-k1", o.fix_k1, "k1 = 0");
  sub.flag("--fix-k2", o.fix_k2, "k2 = 0");
  sub.flag("--fix-k3", o.fix_k3, "k3 = 0");
  sub.flag("--rational", o.rational, "Estimate k4, k5, k6 (rational model)");
  sub.option("--lens-model", lens_model,
             "Lens model: rational-brown (OpenCV's) or kannala-brandt (fisheye, wide angles)")
      .one_of({"rational-brown", "kannala-brandt"});
  sub.option("--outlier-false-alarm", o.outlier_false_alarm,
             "Probability of rejecting any point of a clean set")
      .range(0.0, 0.5);
  sub.flag("--no-outlier-rejection", no_outlier_rejection, "Keep every point");
  sub.option("--min-views", o.min_views, "Fewest board poses accepted (per camera)")
      .range(2, 100000);
  sub.option("--board-deflection", board_deflection,
             "Fit the board's bowl (mrcal's calobject_warp): auto = where identifiable")
      .one_of({"on", "off", "auto"});
}

calib::BoardDeflection deflection_mode(const std::string& name) {
  if (name == "on") return calib::BoardDeflection::on;
  if (name == "off") return calib::BoardDeflection::off;
  return calib::BoardDeflection::automatic;  // one_of admits nothing else
}

void add_model_check_option(cli::Command& sub, bool& no_model_check) {
  sub.flag("--no-model-check", no_model_check,
           "Skip the model error check (cross-validation, residual map): faster");
}

void add_intrinsic(cli::Command& app, IntrinsicArgs& a) {
  cli::Command& sub = app.subcommand("intrinsic", "One camera's intrinsics with covariance");
  sub.option("observations", a.observations, "Observation CSV").required().existing_file();
  sub.option("--camera", a.camera, "Camera to calibrate").range(0, 255);
  sub.option("--unit", a.unit_id, "Unit id written to the calibration file").range(0, 255);
  sub.option("--image-size", a.image_size, "WxH, when the CSV has no image_size line");
  add_model_options(sub, a.options, a.lens_model, a.no_outlier_rejection, a.board_deflection);
  add_model_check_option(sub, a.no_model_check);
  sub.option("-o,--output", a.output, "Rig calibration JSON to write").required();
  sub.option("--residuals", a.residuals_csv, "Per-point residual CSV to write");
}

void add_rig(cli::Command& app, RigArgs& a) {
  cli::Command& sub = app.subcommand(
      "rig", "All cameras jointly (bundle adjustment, camera 0 = reference) with covariance");
  sub.option("observations", a.observations, "Observation CSVs (merged)")
      .required()
      .existing_file();
  sub.option("--unit", a.unit_id, "Unit id written to the calibration file").range(0, 255);
  sub.option("--image-size", a.image_sizes,
             "CAMERA=WxH, when a CSV has no image_size line (repeatable)");
  add_model_options(sub, a.options.intrinsic, a.lens_model, a.no_outlier_rejection,
                    a.board_deflection);
  add_model_check_option(sub, a.no_model_check);
  sub.option("--min-common-views", a.options.min_common_views,
             "Fewest frames two cameras must share to be linked")
      .range(1, 100000);
  sub.option("-o,--output", a.output, "Rig calibration JSON to write").required();
  sub.option("--residuals", a.residuals_csv, "Per-point residual CSV to write");
}

}  // namespace

int parse_calib_command(int argc, char** argv, CalibCommand& command) {
  cli::Command app{"storetrack-calib: camera calibration with covariance (docs/calibration.md)"};
  app.require_subcommand(1);
  add_detect(app, command.detect);
  add_intrinsic(app, command.intrinsic);
  add_rig(app, command.rig);
  add_register(app, command.register_args);
  add_compare(app, command.compare);
  add_uncertainty_map(app, command.uncertainty_map);
  add_triangulate(app, command.triangulate);
  if (const int rc = app.parse(argc, argv); rc >= 0) return rc;
  if (app.got_subcommand("detect")) command.kind = CalibCommand::Kind::kDetect;
  if (app.got_subcommand("intrinsic")) {
    command.kind = CalibCommand::Kind::kIntrinsic;
    if (command.intrinsic.no_outlier_rejection) command.intrinsic.options.outlier_false_alarm = 0;
    command.intrinsic.options.board_deflection =
        deflection_mode(command.intrinsic.board_deflection);
    command.intrinsic.options.lens_model =
        *camera::lens_model_from_name(command.intrinsic.lens_model);
  }
  if (app.got_subcommand("rig")) {
    command.kind = CalibCommand::Kind::kRig;
    if (command.rig.no_outlier_rejection) command.rig.options.intrinsic.outlier_false_alarm = 0;
    command.rig.options.intrinsic.board_deflection = deflection_mode(command.rig.board_deflection);
    command.rig.options.intrinsic.lens_model =
        *camera::lens_model_from_name(command.rig.lens_model);
  }
  if (app.got_subcommand("register")) command.kind = CalibCommand::Kind::kRegister;
  if (app.got_subcommand("compare")) command.kind = CalibCommand::Kind::kCompare;
  if (app.got_subcommand("uncertainty-map")) command.kind = CalibCommand::Kind::kUncertaintyMap;
  if (app.got_subcommand("triangulate")) command.kind = CalibCommand::Kind::kTriangulate;
  return -1;
}

}  // namespace storetrack::calibapp
