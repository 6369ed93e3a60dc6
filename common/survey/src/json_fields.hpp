// Strict JSON field access shared by the survey and scale-bar readers (internal): every
// refusal names the file and the field.
#pragma once

#include <string>

#include <nlohmann/json.hpp>

#include "storetrack/survey/survey.hpp"

namespace storetrack::survey::detail {

[[noreturn]] inline void fail(const std::string& origin, const std::string& field,
                              const std::string& why) {
  throw SurveyFileError(origin + ": field '" + field + "': " + why);
}

/// obj[key]; the field is named `prefix` + key ("$.name", "bars[2].mark_a"), the object itself
/// `prefix` without its trailing '.'.
inline const nlohmann::json& require(const nlohmann::json& obj, const char* key,
                                     const std::string& origin, const std::string& prefix) {
  if (!obj.is_object())
    fail(origin, prefix.empty() ? "$" : prefix.substr(0, prefix.size() - 1), "expected an object");
  const auto it = obj.find(key);
  if (it == obj.end()) fail(origin, prefix + key, "missing");
  return *it;
}

}  // namespace storetrack::survey::detail
