// storetrack-calib compare / uncertainty-map (docs/calibration.md, "Compare", "Uncertainty
// map"): two calibrations of one rig compared, with a verdict; the predicted 3-D uncertainty of
// a triangulated mark over the working volume. Each writes a result JSON and prints a summary;
// host/report/storetrack_calib_report.py turns the JSON into HTML + PNG.
#pragma once

#include <ostream>
#include <string>
#include <vector>

#include "storetrack/calib/calibration_comparison.hpp"
#include "storetrack/cli/command_line.hpp"

namespace storetrack::calibapp {

/// Working volume and grid options shared by both subcommands.
struct VolumeArgs {
  std::vector<double> distances_m;  ///< empty: from the rig
  std::vector<double> volume;       ///< x0,x1,y0,y1,z0,z1 [m, world]; empty: from the rig
  int points_per_axis = 0;          ///< 0: the subcommand's default
  double sigma_px = 0.05;
};

struct CompareArgs {
  std::string a, b;
  VolumeArgs volume;
  std::string scale_bars;    ///< storetrack-scale-bars JSON (optional)
  std::string observations;  ///< observation CSV of the bars' marks (point_id = mark id)
  double point_false_alarm = 0.01;
  double false_alarm = 0.01;
  int min_points_per_cell = 10;  ///< observed_region cells with fewer count as unobserved
  std::string output;
};

struct UncertaintyMapArgs {
  std::string rig;
  VolumeArgs volume;
  std::string output;
};

void add_compare(cli::Command& app, CompareArgs& args);
void add_uncertainty_map(cli::Command& app, UncertaintyMapArgs& args);
int run_compare(const CompareArgs& args, std::ostream& out, std::ostream& err);
int run_uncertainty_map(const UncertaintyMapArgs& args, std::ostream& out, std::ostream& err);

/// The result documents (what the commands write).
std::string comparison_json(const calib::ComparisonResult& r, const CompareArgs& args);
std::string uncertainty_map_json(const calib::UncertaintyMap& m, const UncertaintyMapArgs& args);

}  // namespace storetrack::calibapp
