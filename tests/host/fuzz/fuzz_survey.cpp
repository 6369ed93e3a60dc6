// libFuzzer target: the mark survey reader (common/survey parse_survey, read by storetrack-host for
// the pylon and store surveys) on arbitrary text. Properties checked (abort when violated),
// beyond "no crash, no UB":
//  - a refusal is a SurveyFileError naming the origin; no other exception escapes (a JSON number
//    too large for a double included);
//  - an accepted survey has a name, a one-letter frame, a positive finite mark diameter and at
//    least one mark; mark ids are unique, positions finite, sigmas finite and >= 0;
//  - every mark id is the integer the file wrote (no silent wrap of 4294967396 to 100);
//  - it survives the writer exactly: parse(format(survey)) gives the same survey.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <set>
#include <string>

#include <nlohmann/json.hpp>

#include "storetrack/survey/survey.hpp"

namespace {

namespace survey = storetrack::survey;

void check_valid(const survey::RigidBodySurvey& s) {
  if (s.name.empty() || s.marks.empty()) std::abort();
  if (!(s.mark_diameter_m > 0) || !std::isfinite(s.mark_diameter_m)) std::abort();
  std::set<int> ids;
  for (const auto& m : s.marks) {
    if (!ids.insert(m.id).second) std::abort();
    if (!m.p_body.allFinite() || !(m.sigma_m >= 0) || !std::isfinite(m.sigma_m)) std::abort();
  }
}

// The ids as the file wrote them, read independently of the reader's conversion.
void check_ids_as_written(const survey::RigidBodySurvey& s, const std::string& text) {
  const auto root = nlohmann::json::parse(text);
  const auto& marks = root.at("marks");
  if (marks.size() != s.marks.size()) std::abort();
  for (std::size_t i = 0; i < marks.size(); ++i) {
    const auto& id = marks[i].at("id");
    const bool same = id.is_number_unsigned()
                          ? s.marks[i].id >= 0 &&
                                id.get<std::uint64_t>() == static_cast<std::uint64_t>(s.marks[i].id)
                          : id.get<std::int64_t>() == s.marks[i].id;
    if (!same) std::abort();
  }
}

void check_round_trip(const survey::RigidBodySurvey& s) {
  survey::RigidBodySurvey again;
  try {
    again = survey::parse_survey(survey::format_survey(s), "round trip");
  } catch (const survey::SurveyFileError&) {
    std::abort();  // the writer wrote what the reader refuses
  }
  if (again.name != s.name || again.frame != s.frame) std::abort();
  if (again.mark_diameter_m != s.mark_diameter_m || again.marks.size() != s.marks.size())
    std::abort();
  for (std::size_t i = 0; i < s.marks.size(); ++i) {
    const auto& a = s.marks[i];
    const auto& b = again.marks[i];
    if (a.id != b.id || a.p_body != b.p_body || a.sigma_m != b.sigma_m) std::abort();
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  survey::RigidBodySurvey survey;
  try {
    survey = survey::parse_survey(text, "fuzz.json");
  } catch (const survey::SurveyFileError& e) {
    if (std::string(e.what()).rfind("fuzz.json: ", 0) != 0) std::abort();
    return 0;
  }
  check_valid(survey);
  check_ids_as_written(survey, text);
  check_round_trip(survey);
  return 0;
}
