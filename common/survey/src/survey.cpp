#include "storetrack/survey/survey.hpp"

#include <fstream>
#include <limits>
#include <set>

#include <nlohmann/json.hpp>

#include "storetrack/json/text_file.hpp"

namespace storetrack::survey {

using jsonfile::Object;
using jsonfile::Range;
using jsonfile::Value;

const SurveyedMark* RigidBodySurvey::find(int id) const {
  for (const SurveyedMark& m : marks)
    if (m.id == id) return &m;
  return nullptr;
}

RigidBodySurvey read_survey(const Value& value) {
  Object root = value.object();
  if (const auto f = root.find("format"); f && f->string() != "storetrack-survey")
    f->fail("expected \"storetrack-survey\"");
  if (const auto v = root.find("version"); v && v->json() != 1)
    v->fail("unsupported version (expected 1)");
  RigidBodySurvey s;
  s.name = root.at("name").non_empty_string();
  const Value frame = root.at("frame");
  const std::string letter = frame.string();
  if (letter.size() != 1) frame.fail("expected a one-letter frame name");
  s.frame = letter[0];
  s.mark_diameter_m = root.at("mark_diameter_m").number(Range::above(0));
  std::set<int> ids;
  for (const Value& entry : root.at("marks").array(1, std::numeric_limits<std::size_t>::max())) {
    Object m = entry.object();
    SurveyedMark mark;
    const Value id = m.at("id");
    // An id outside int would wrap silently onto another mark's (4294967396 -> 100).
    mark.id = id.as<int>();
    if (!ids.insert(mark.id).second) id.fail("duplicate mark id");
    const std::vector<double> p = m.at("p_body_m").numbers(3);
    mark.p_body = geometry::Vec3(p[0], p[1], p[2]);
    mark.sigma_m = m.at("sigma_m").number(Range::at_least(0));
    m.finish();
    s.marks.push_back(mark);
  }
  if (const auto cg = root.find("cg")) {
    Object c = cg->object();
    const std::vector<double> p = c.at("p_body_m").numbers(3);
    s.cg =
        SurveyedPoint{geometry::Vec3(p[0], p[1], p[2]), c.at("sigma_m").number(Range::at_least(0))};
    c.finish();
  }
  root.finish();
  return s;
}

RigidBodySurvey parse_survey(const std::string& json_text, const std::string& origin) {
  try {
    const jsonfile::Document doc = jsonfile::Document::parse(json_text, origin);
    return read_survey(doc.root());
  } catch (const jsonfile::FieldError& e) {
    throw SurveyFileError(e.what());
  }
}

RigidBodySurvey read_survey(const std::string& path) {
  std::string text;
  try {
    text = jsonfile::read_text_file(path);
  } catch (const jsonfile::FileReadError& e) {
    throw SurveyFileError(std::string(e.what()) + " (survey file)");
  }
  return parse_survey(text, path);
}

std::string format_survey(const RigidBodySurvey& survey) {
  using nlohmann::json;
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
  if (survey.cg)
    root["cg"] = {
        {"p_body_m", {survey.cg->p_body.x(), survey.cg->p_body.y(), survey.cg->p_body.z()}},
        {"sigma_m", survey.cg->sigma_m}};
  return root.dump(2) + "\n";
}

void write_survey(const RigidBodySurvey& survey, const std::string& path) {
  std::ofstream out(path);
  if (!out) throw SurveyFileError(path + ": cannot open for writing");
  out << format_survey(survey);
  if (!out) throw SurveyFileError(path + ": write failed");
}

}  // namespace storetrack::survey
