#include "storetrack/survey/survey.hpp"

#include <cmath>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>

#include "json_fields.hpp"

namespace storetrack::survey {
namespace {

using nlohmann::json;

using detail::fail;
using detail::require;

double finite_number(const json& v, const std::string& origin, const std::string& path) {
  if (!v.is_number()) fail(origin, path, "expected a number");
  const double d = v.get<double>();
  if (!std::isfinite(d)) fail(origin, path, "not finite");
  return d;
}

}  // namespace

const SurveyedMark* RigidBodySurvey::find(int id) const {
  for (const SurveyedMark& m : marks)
    if (m.id == id) return &m;
  return nullptr;
}

RigidBodySurvey parse_survey(const std::string& json_text, const std::string& origin) {
  json root;
  try {
    root = json::parse(json_text);
  } catch (const json::exception& e) {  // parse_error, or out_of_range for a number overflow
    throw SurveyFileError(origin + ": not valid JSON: " + e.what());
  }
  if (!root.is_object()) fail(origin, "$", "expected a JSON object");
  if (const auto it = root.find("format"); it != root.end() && *it != "storetrack-survey") {
    fail(origin, "format", "expected \"storetrack-survey\"");
  }
  if (const auto it = root.find("version"); it != root.end() && *it != 1) {
    fail(origin, "version", "unsupported version (expected 1)");
  }
  RigidBodySurvey s;
  const json& name = require(root, "name", origin, "$.");
  if (!name.is_string() || name.get<std::string>().empty()) fail(origin, "name", "expected a name");
  s.name = name.get<std::string>();
  const json& frame = require(root, "frame", origin, "$.");
  if (!frame.is_string() || frame.get<std::string>().size() != 1) {
    fail(origin, "frame", "expected a one-letter frame name");
  }
  s.frame = frame.get<std::string>()[0];
  s.mark_diameter_m =
      finite_number(require(root, "mark_diameter_m", origin, "$."), origin, "mark_diameter_m");
  if (s.mark_diameter_m <= 0) fail(origin, "mark_diameter_m", "must be > 0");
  const json& marks = require(root, "marks", origin, "$.");
  if (!marks.is_array() || marks.empty()) fail(origin, "marks", "expected a non-empty array");
  std::set<int> ids;
  for (std::size_t i = 0; i < marks.size(); ++i) {
    const std::string path = "marks[" + std::to_string(i) + "]";
    const json& m = marks[i];
    SurveyedMark mark;
    const json& id = require(m, "id", origin, path + ".");
    // An id outside int would wrap silently onto another mark's (4294967396 -> 100).
    const bool in_range = id.is_number_unsigned()
                              ? id.get<std::uint64_t>() <= std::numeric_limits<int>::max()
                              : id.is_number_integer() &&
                                    id.get<std::int64_t>() >= std::numeric_limits<int>::min() &&
                                    id.get<std::int64_t>() <= std::numeric_limits<int>::max();
    if (!in_range) fail(origin, path + ".id", "expected an integer in the range of int");
    mark.id = static_cast<int>(id.get<std::int64_t>());
    if (!ids.insert(mark.id).second) fail(origin, path + ".id", "duplicate mark id");
    const json& p = require(m, "p_body_m", origin, path + ".");
    if (!p.is_array() || p.size() != 3) fail(origin, path + ".p_body_m", "expected [x, y, z]");
    for (int k = 0; k < 3; ++k) {
      mark.p_body[k] = finite_number(p[static_cast<std::size_t>(k)], origin,
                                     path + ".p_body_m[" + std::to_string(k) + "]");
    }
    mark.sigma_m =
        finite_number(require(m, "sigma_m", origin, path + "."), origin, path + ".sigma_m");
    if (mark.sigma_m < 0) fail(origin, path + ".sigma_m", "must be >= 0");
    s.marks.push_back(mark);
  }
  return s;
}

RigidBodySurvey read_survey(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw SurveyFileError(path + ": cannot open survey file");
  std::stringstream buf;
  buf << in.rdbuf();
  return parse_survey(buf.str(), path);
}

std::string format_survey(const RigidBodySurvey& survey) {
  json root;
  root["format"] = "storetrack-survey";
  root["version"] = 1;
  root["name"] = survey.name;
  root["frame"] = std::string(1, survey.frame);
  root["mark_diameter_m"] = survey.mark_diameter_m;
  json marks = json::array();
  for (const SurveyedMark& m : survey.marks) {
    marks.push_back({{"id", m.id},
                     {"p_body_m", {m.p_body.x(), m.p_body.y(), m.p_body.z()}},
                     {"sigma_m", m.sigma_m}});
  }
  root["marks"] = marks;
  return root.dump(2) + "\n";
}

void write_survey(const RigidBodySurvey& survey, const std::string& path) {
  std::ofstream out(path);
  if (!out) throw SurveyFileError(path + ": cannot open for writing");
  out << format_survey(survey);
  if (!out) throw SurveyFileError(path + ": write failed");
}

}  // namespace storetrack::survey
