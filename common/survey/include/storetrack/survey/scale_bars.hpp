// Calibrated scale bars (VDI/VDE 2634-1 length artefacts): each bar carries two marks whose
// centre distance a calibration laboratory (or CMM) measured, with its standard uncertainty.
// Read by storetrack-eval lme (docs/evaluation.md), written by the simulator from its truth.
//
// File format (JSON, SI units):
//   { "format": "storetrack-scale-bars", "version": 1, "name": "bar set 2026-12",
//     "bars": [ {"id": "diagonal_1", "mark_a": 300, "mark_b": 301,
//                "length_m": 0.99912, "u_length_m": 5e-06}, ... ] }
// "length_m" is the calibrated distance between the centres of mark_a and mark_b, "u_length_m"
// its standard uncertainty (k = 1) from the calibration certificate.
#pragma once

#include <string>
#include <vector>

#include "storetrack/survey/survey.hpp"

namespace storetrack::survey {

struct ScaleBar {
  std::string id;
  int mark_a = 0, mark_b = 0;
  double length_m = 0;    ///< calibrated centre distance of the two marks [m]
  double u_length_m = 0;  ///< its standard uncertainty [m]
};

struct ScaleBarSet {
  std::string name;
  std::vector<ScaleBar> bars;
};

/// Throws SurveyFileError naming the file and the field (e.g. "bars[2].mark_b").
ScaleBarSet read_scale_bars(const std::string& path);
ScaleBarSet parse_scale_bars(const std::string& json_text, const std::string& origin);
std::string format_scale_bars(const ScaleBarSet& set);
void write_scale_bars(const ScaleBarSet& set, const std::string& path);

}  // namespace storetrack::survey
