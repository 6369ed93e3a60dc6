// The scale-bar definition file, read strictly: a bar with a mistyped mark or length must stop
// the evaluation with the file and field, never yield a silently wrong length error.
#include "storetrack/survey/scale_bars.hpp"

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

int mark_id(const json& v, const std::string& origin, const std::string& path) {
  if (!v.is_number_integer() || v.get<long long>() < 0 ||
      v.get<long long>() > std::numeric_limits<int>::max())
    fail(origin, path, "expected a mark id (a non-negative integer)");
  return v.get<int>();
}

double positive(const json& v, const std::string& origin, const std::string& path, bool zero_ok) {
  if (!v.is_number()) fail(origin, path, "expected a number [m]");
  const double d = v.get<double>();
  if (!std::isfinite(d) || d < 0 || (!zero_ok && d == 0))
    fail(origin, path, zero_ok ? "must be finite and >= 0" : "must be finite and > 0");
  return d;
}

ScaleBar parse_bar(const json& b, const std::string& origin, const std::string& path) {
  if (!b.is_object()) fail(origin, path, "expected an object");
  ScaleBar bar;
  const json& id = require(b, "id", origin, path + ".");
  if (!id.is_string() || id.get<std::string>().empty())
    fail(origin, path + ".id", "expected a non-empty string");
  bar.id = id.get<std::string>();
  bar.mark_a = mark_id(require(b, "mark_a", origin, path + "."), origin, path + ".mark_a");
  bar.mark_b = mark_id(require(b, "mark_b", origin, path + "."), origin, path + ".mark_b");
  if (bar.mark_a == bar.mark_b) fail(origin, path + ".mark_b", "the same mark as mark_a");
  bar.length_m =
      positive(require(b, "length_m", origin, path + "."), origin, path + ".length_m", false);
  bar.u_length_m =
      positive(require(b, "u_length_m", origin, path + "."), origin, path + ".u_length_m", true);
  return bar;
}

}  // namespace

ScaleBarSet parse_scale_bars(const std::string& json_text, const std::string& origin) {
  json root;
  try {
    root = json::parse(json_text);
  } catch (const json::exception& e) {
    throw SurveyFileError(origin + ": not valid JSON: " + e.what());
  }
  if (!root.is_object()) fail(origin, "$", "expected a JSON object");
  if (root.value("format", std::string()) != "storetrack-scale-bars")
    fail(origin, "format", "expected \"storetrack-scale-bars\"");
  if (const auto it = root.find("version"); it == root.end() || *it != 1)
    fail(origin, "version", "unsupported or missing version (expected 1)");
  ScaleBarSet set;
  if (const auto it = root.find("name"); it != root.end() && it->is_string())
    set.name = it->get<std::string>();
  const json& bars = require(root, "bars", origin, "");
  if (!bars.is_array() || bars.empty()) fail(origin, "bars", "expected a non-empty array");
  std::set<std::string> ids;
  std::set<int> marks;
  for (size_t i = 0; i < bars.size(); ++i) {
    const std::string path = "bars[" + std::to_string(i) + "]";
    ScaleBar bar = parse_bar(bars[i], origin, path);
    if (!ids.insert(bar.id).second) fail(origin, path + ".id", "duplicate bar id '" + bar.id + "'");
    // A mark shared by two bars would make their length errors correlated through one centroid.
    if (!marks.insert(bar.mark_a).second) fail(origin, path + ".mark_a", "mark used by two bars");
    if (!marks.insert(bar.mark_b).second) fail(origin, path + ".mark_b", "mark used by two bars");
    set.bars.push_back(std::move(bar));
  }
  return set;
}

ScaleBarSet read_scale_bars(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw SurveyFileError(path + ": cannot open the scale-bar file");
  std::stringstream buf;
  buf << in.rdbuf();
  return parse_scale_bars(buf.str(), path);
}

std::string format_scale_bars(const ScaleBarSet& set) {
  json bars = json::array();
  for (const ScaleBar& b : set.bars)
    bars.push_back({{"id", b.id},
                    {"mark_a", b.mark_a},
                    {"mark_b", b.mark_b},
                    {"length_m", b.length_m},
                    {"u_length_m", b.u_length_m}});
  json root = {{"format", "storetrack-scale-bars"}, {"version", 1}, {"name", set.name}};
  root["bars"] = bars;
  return root.dump(2) + "\n";
}

void write_scale_bars(const ScaleBarSet& set, const std::string& path) {
  std::ofstream out(path);
  if (!out) throw SurveyFileError(path + ": cannot open for writing");
  out << format_scale_bars(set);
  if (!out) throw SurveyFileError(path + ": write failed");
}

}  // namespace storetrack::survey
