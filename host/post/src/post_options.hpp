// storetrack-post's command line: the recording's files, the outputs, and the inputs that
// replace the recorded ones.
#pragma once

#include <string>
#include <vector>

namespace storetrack::post {

struct PostOptions {
  std::vector<std::string> recording_files;  ///< one host run's files, in the order written
  bool verify = false;
  std::string csv_path, stats_json_path;
  /// The reprocessed run as a new Chapter 10 recording (new file; reprocessed_recording.hpp).
  std::string output_ch10_path;
  std::string smoothed_csv_path;  ///< the fixed-interval smoother's trajectory (new file)
  std::string product_csv_path;   ///< the store-separation data product (new file)
  /// Per sample and axis, the substituted input's change against its uncertainty (new file).
  std::string differences_csv_path;
  /// The same for the smoothed trajectory: both runs smoothed (new file).
  std::string smoothed_differences_csv_path;
  std::string clearance_csv_path;  ///< every aircraft part's clearance per sample (new file)
  /// The truth-free report's data (new or empty directory; host/report renders it).
  std::string report_dir;
  /// Read from disk instead of the recording (empty: the recorded one).
  std::string calibration_path, pylon_path, store_path, config_path;
  /// The clearance geometry file (and the STL files it names) from disk instead of the recorded.
  std::string clearance_geometry_path;
  std::string log_level = "warn";
};

/// Parses argv into `o`; returns -1 to go on, else the exit code (0 for --help, 2 for an error).
int parse_post_options(int argc, char** argv, PostOptions& o);

}  // namespace storetrack::post
