// The scale-bar definition file, read strictly: a bar with a mistyped mark or length must stop
// the evaluation with the file and field, never yield a silently wrong length error.
#include "storetrack/survey/scale_bars.hpp"

#include <fstream>
#include <limits>
#include <set>

#include <nlohmann/json.hpp>

#include "storetrack/json/text_file.hpp"

namespace storetrack::survey {
namespace {

using jsonfile::Object;
using jsonfile::Range;
using jsonfile::Value;

int mark_id(const Value& v) {
  return static_cast<int>(v.integer(0, std::numeric_limits<int>::max()));
}

ScaleBar parse_bar(const Value& value) {
  Object b = value.object();
  ScaleBar bar;
  bar.id = b.at("id").non_empty_string();
  bar.mark_a = mark_id(b.at("mark_a"));
  const Value mark_b = b.at("mark_b");
  bar.mark_b = mark_id(mark_b);
  if (bar.mark_a == bar.mark_b) mark_b.fail("the same mark as mark_a");
  bar.length_m = b.at("length_m").number(Range::above(0));
  bar.u_length_m = b.at("u_length_m").number(Range::at_least(0));
  b.finish();
  return bar;
}

ScaleBarSet read_scale_bars(const Value& value) {
  Object root = value.object();
  if (const Value f = root.at("format"); f.json() != "storetrack-scale-bars")
    f.fail("expected \"storetrack-scale-bars\"");
  if (const Value v = root.at("version"); v.json() != 1) v.fail("unsupported version (expected 1)");
  ScaleBarSet set;
  root.get("name", set.name);
  std::set<std::string> ids;
  std::set<int> marks;
  for (const Value& entry : root.at("bars").array(1, std::numeric_limits<std::size_t>::max())) {
    ScaleBar bar = parse_bar(entry);
    if (!ids.insert(bar.id).second) entry.fail_member("id", "duplicate bar id '" + bar.id + "'");
    // A mark shared by two bars would make their length errors correlated through one centroid.
    if (!marks.insert(bar.mark_a).second) entry.fail_member("mark_a", "mark used by two bars");
    if (!marks.insert(bar.mark_b).second) entry.fail_member("mark_b", "mark used by two bars");
    set.bars.push_back(std::move(bar));
  }
  root.finish();
  return set;
}

}  // namespace

ScaleBarSet parse_scale_bars(const std::string& json_text, const std::string& origin) {
  try {
    const jsonfile::Document doc = jsonfile::Document::parse(json_text, origin);
    return read_scale_bars(doc.root());
  } catch (const jsonfile::FieldError& e) {
    throw SurveyFileError(e.what());
  }
}

ScaleBarSet read_scale_bars(const std::string& path) {
  std::string text;
  try {
    text = jsonfile::read_text_file(path);
  } catch (const jsonfile::FileReadError& e) {
    throw SurveyFileError(std::string(e.what()) + " (scale-bar file)");
  }
  return parse_scale_bars(text, path);
}

std::string format_scale_bars(const ScaleBarSet& set) {
  using nlohmann::json;
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
