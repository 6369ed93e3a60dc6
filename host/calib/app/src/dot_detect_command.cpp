#include "dot_detect_command.hpp"

#include <cstdio>

#include "calib_cli.hpp"
#include "command_output.hpp"

namespace storetrack::calibapp {

void add_dot_detect_options(cli::Command& sub, DotDetectArgs& a) {
  sub.option("--spacing", a.grid.spacing_m, "Dot grid: centre-to-centre spacing [m]").positive();
  sub.flag("--light-dots", a.light_dots,
           "Dot grid: bright (retro-reflective, white) dots on a dark ground; default dark dots");
  sub.option("--origin-col", a.grid.origin_col, "Ring dots: grid column of the origin ring dot")
      .range(0, 1000);
  sub.option("--origin-row", a.grid.origin_row, "Ring dots: grid row of the origin ring dot")
      .range(0, 1000);
  sub.option("--origin-to-x", a.grid.origin_to_x_marker,
             "Ring dots: the x marker is this many dots from the origin along +x, origin counted")
      .range(2, 1000);
  sub.option("--origin-to-y", a.grid.origin_to_y_marker,
             "Ring dots: the y marker is this many dots from the origin along +y, origin counted")
      .range(2, 1000);
  sub.option("--gain", a.centroid.gain_e_per_dn,
             "Dot grid: camera conversion gain [e-/DN] for the centroider's sigma")
      .positive();
  sub.option("--read-noise", a.centroid.read_noise_e,
             "Dot grid: camera read noise [e-] for the centroider's sigma")
      .range(0.0, 1e6);
}

int run_dot_detect(const DetectArgs& args, std::ostream& out, std::ostream& err) {
  calib::DotGridSpec grid = args.dots.grid;
  grid.kind = args.board == "dots" ? calib::DotBoardKind::kDots : calib::DotBoardKind::kRingDots;
  grid.cols = args.chessboard.cols;
  grid.rows = args.chessboard.rows;
  grid.dark_dots = !args.dots.light_dots;
  calib::DotDetectionResult result;
  try {
    result = calib::detect_dot_grids(args.images, grid, args.dots.centroid, args.camera);
  } catch (const std::invalid_argument& e) {
    err << "error: " << e.what() << "\n";
    return 2;
  }
  for (const auto& rejected : result.rejected)
    err << "rejected " << rejected.path << ": " << rejected.reason << "\n";
  for (const auto& dot : result.rejected_dots) {
    char at[64];
    std::snprintf(at, sizeof at, "(%.1f, %.1f) px", dot.pixel.x(), dot.pixel.y());
    err << "dot not used " << dot.image << " " << at << ": " << dot.reason << "\n";
  }
  out << "detect: " << result.images_used << " of " << args.images.size() << " images used, "
      << result.rejected.size() << " rejected, " << result.set.observations.size() << " dots ("
      << grid.cols << "x" << grid.rows << " " << args.board << ", spacing " << grid.spacing_m
      << " m), " << result.rejected_dots.size() << " dots not used\n";
  if (result.images_used == 0) {
    err << "error: no image gave a dot grid; nothing written\n";
    return 2;
  }
  return write_outputs(args.output, out, err,
                       [&] { calib::write_observations_csv(result.set, args.output); });
}

}  // namespace storetrack::calibapp
