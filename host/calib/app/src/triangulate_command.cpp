#include "triangulate_command.hpp"

#include <filesystem>

#include <fmt/format.h>

#include "command_output.hpp"
#include "storetrack/calib/offline_triangulation.hpp"
#include "storetrack/json/text_file.hpp"

namespace storetrack::calibapp {

void add_triangulate(cli::Command& app, TriangulateArgs& a) {
  cli::Command& sub = app.subcommand(
      "triangulate",
      "Pixel observations CSV + rig calibration -> marks CSV (storetrack-eval's input) with the "
      "full covariance, by the host's triangulation");
  sub.option("--calibration", a.calibration, "Rig calibration JSON").required().existing_file();
  sub.option("--observations", a.observations,
             "Pixel observations CSV: exposure, [time_ns,] camera_id, mark_id, u, v, sigma or "
             "cov_uu, cov_uv, cov_vv")
      .required()
      .existing_file();
  sub.option("--out", a.output, "Marks CSV to write (refused if it exists)").required();
  sub.option("--body", a.body, "The marks CSV's body column").one_of({"p", "s", "?"});
}

int run_triangulate(const TriangulateArgs& args, std::ostream& out, std::ostream& err) {
  calib::OfflineTriangulation result;
  try {
    if (std::filesystem::exists(args.output))
      throw std::runtime_error(args.output +
                               ": exists; not overwritten (remove it or give another --out)");
    const camera::RigCalibration rig = camera::read_rig_calibration(args.calibration);
    const auto observations = calib::parse_pixel_observations_csv(
        jsonfile::read_text_file(args.observations), args.observations);
    result =
        calib::triangulate_observations(rig, observations, args.calibration, args.observations);
  } catch (const std::exception& e) {
    err << "error: " << e.what() << "\n";
    return 2;
  }
  out << fmt::format(
      "triangulate: {} marks triangulated, {} seen by one camera only (counted, "
      "not triangulated), {} failed\n",
      result.marks.size(), result.single_camera_marks, result.failed_marks);
  if (result.single_camera_marks > 0)
    err << "warning: " << result.single_camera_marks
        << " (exposure, mark) pairs are seen by one camera only: not triangulated\n";
  return write_outputs(args.output, out, err, [&] {
    write_text(args.output, calib::format_marks_csv(result, args.body[0]));
  });
}

}  // namespace storetrack::calibapp
