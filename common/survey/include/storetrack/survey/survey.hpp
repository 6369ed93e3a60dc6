// Surveys of rigid bodies carrying reference marks (pylon, store, pendulum board, scale bars):
// mark positions in the body frame, measured by total station / CMM with a standard
// uncertainty. Used by the simulator (truth + survey error) and by the host with real surveys.
//
// File format (JSON, SI units, docs/conventions.md frames):
//   { "format": "storetrack-survey", "version": 1,
//     "name": "store", "frame": "s", "mark_diameter_m": 0.030,
//     "marks": [ {"id": 100, "p_body_m": [x, y, z], "sigma_m": 0.0002}, ... ],
//     "cg": {"p_body_m": [x, y, z], "sigma_m": 0.002} }
// "sigma_m" is the isotropic per-axis standard uncertainty of the surveyed position. "cg"
// (optional; a store's) is its centre of gravity in the body frame from the mass-properties
// measurement, with its per-axis standard uncertainty: the store-separation data product needs
// it (storetrack-post --product-csv, docs/post-processing.md).
#pragma once

#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "storetrack/geometry/transform.hpp"
#include "storetrack/json/strict_reader.hpp"

namespace storetrack::survey {

struct SurveyedMark {
  int id = 0;
  geometry::Vec3 p_body = geometry::Vec3::Zero();  ///< position in the body frame [m]
  double sigma_m = 0;                              ///< per-axis standard uncertainty of p_body [m]
};

/// A surveyed point that is not a mark (the store's CG).
struct SurveyedPoint {
  geometry::Vec3 p_body = geometry::Vec3::Zero();  ///< [m], body frame
  double sigma_m = 0;                              ///< per-axis standard uncertainty [m]
};

struct RigidBodySurvey {
  std::string name;  ///< "pylon", "store", "pendulum", "scale_bar_N"
  char frame = 'b';  ///< frame letter of docs/conventions.md ('p', 's', 'b')
  std::vector<SurveyedMark> marks;
  double mark_diameter_m = 0;       ///< diameter of the retro-reflective discs [m]
  std::optional<SurveyedPoint> cg;  ///< centre of gravity ("cg"; absent: not given)

  /// The mark with this id, or nullptr.
  const SurveyedMark* find(int id) const;
};

/// Thrown on malformed survey files; what() names the file (origin), the field and why.
class SurveyFileError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

RigidBodySurvey read_survey(const std::string& path);
/// Parses JSON text; `origin` (file name) is used in error messages.
RigidBodySurvey parse_survey(const std::string& json_text, const std::string& origin);
/// A survey held in a larger file (a scenario's "pylon_survey"): refusals throw
/// jsonfile::FieldError with the survey's path in that file.
RigidBodySurvey read_survey(const jsonfile::Value& value);
std::string format_survey(const RigidBodySurvey& survey);
/// Writes the survey; throws SurveyFileError when the file cannot be written.
void write_survey(const RigidBodySurvey& survey, const std::string& path);

}  // namespace storetrack::survey
