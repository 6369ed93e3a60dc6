#include "post_options.hpp"

#include "storetrack/cli/command_line.hpp"

namespace storetrack::post {

int parse_post_options(int argc, char** argv, PostOptions& o) {
  cli::Command app{
      "storetrack-post: replays a storetrack-host recording (IRIG 106 Chapter 10 with the raw "
      "observation channel) through the host's aligner, matcher and processor"};
  app.option("recording", o.recording_files,
             "The Chapter 10 files of one host run, in the order the host wrote them")
      .required()
      .existing_file();
  app.flag("--verify", o.verify,
           "Compare every replayed sample byte for byte with the recorded one (exit 1 on any "
           "difference or a different count)");
  app.option("--csv", o.csv_path, "Write the replayed samples to this NEW CSV file");
  app.option("--output-ch10", o.output_ch10_path,
             "Write the reprocessed run as a NEW Chapter 10 recording (the host's writer): the "
             "replayed samples, the raw channel copied, the inputs used (substitutes included) "
             "with their SHA-256, TMATS naming the source and the substitutes; it can be "
             "reprocessed again");
  app.option("--smoothed-csv", o.smoothed_csv_path,
             "Write the smoothed trajectory (pose, velocity, acceleration, angular rate with "
             "their uncertainty, noise and shared parts) to this NEW CSV file");
  app.option("--product-csv", o.product_csv_path,
             "Write the store-separation data product (time since the detected release t0; CG "
             "position, displacement from the carriage, Euler angles, CG velocity and "
             "acceleration, body rates, in pylon and aircraft axes, each with u and U) to this NEW "
             "CSV file; needs the store survey's \"cg\"");
  app.option("--differences-csv", o.differences_csv_path,
             "With a substituted input: write per sample and axis how far the pose moved from "
             "the recorded inputs' (d), the standard uncertainty of that difference (u) and z = "
             "d / u to this NEW CSV file");
  app.option("--smoothed-differences-csv", o.smoothed_differences_csv_path,
             "With a substituted input: smooth both runs and write per smoothed exposure and "
             "quantity (position, attitude, velocity, acceleration, angular rate and "
             "acceleration) the difference d, the standard uncertainty of that difference u, z = "
             "d / u and |z| > 2 to this NEW CSV file");
  app.option("--clearance-csv", o.clearance_csv_path,
             "Write every aircraft part's clearance per written sample (the host's --clearance-csv "
             "columns: distance, u, k = 2 lower bound, the two closest points, the normal) to this "
             "NEW CSV file; needs the clearance geometry (recorded or --clearance-geometry)");
  app.option("--report", o.report_dir,
             "Write the truth-free report's data to this NEW (or empty) directory: the replayed "
             "samples, the smoothed trajectory, the data product (with the store's CG), residuals "
             "per camera and exposure, camera usage, the recording's integrity; render it with "
             "host/report/storetrack_post_report.py DIR");
  app.option("--stats-json", o.stats_json_path,
             "Write the replay's counters and the comparison to this NEW JSON file");
  app.option("--calibration", o.calibration_path, "Use this rig calibration, not the recorded")
      .existing_file();
  app.option("--pylon-survey", o.pylon_path, "Use this pylon survey, not the recorded")
      .existing_file();
  app.option("--store-survey", o.store_path, "Use this store survey, not the recorded")
      .existing_file();
  app.option("--config", o.config_path, "Use this host configuration, not the recorded")
      .existing_file();
  app.option("--clearance-geometry", o.clearance_geometry_path,
             "Use this clearance geometry file (and the STL files it names), not the recorded")
      .existing_file();
  app.option("--log-level", o.log_level, "spdlog level")
      .one_of({"trace", "debug", "info", "warn", "error", "off"})
      .show_default();
  return app.parse(argc, argv);
}

}  // namespace storetrack::post
