#include "storetrack/json/strict_reader.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <utility>

#include "storetrack/json/text_file.hpp"

namespace storetrack::jsonfile {
namespace {

std::string message(const std::string& file, const std::string& path, const std::string& reason) {
  std::string m = file;
  if (!path.empty()) m += (m.empty() ? "" : ": ") + path;
  return m + (m.empty() ? "" : ": ") + reason;
}

// Optimal string alignment distance: insertions, deletions, substitutions and swaps of two
// neighbouring letters ("prot" -> "port") each count one.
std::size_t edit_distance(const std::string& a, const std::string& b) {
  const std::size_t n = a.size(), m = b.size();
  std::vector<std::vector<std::size_t>> d(n + 1, std::vector<std::size_t>(m + 1));
  for (std::size_t i = 0; i <= n; ++i)
    d[i][0] = i;
  for (std::size_t j = 0; j <= m; ++j)
    d[0][j] = j;
  for (std::size_t i = 1; i <= n; ++i) {
    for (std::size_t j = 1; j <= m; ++j) {
      const std::size_t cost = a[i - 1] == b[j - 1] ? 0 : 1;
      d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + cost});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1])
        d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
    }
  }
  return d[n][m];
}

std::string type_name(const nlohmann::json& v) {
  if (v.is_number_integer()) return "an integer";
  if (v.is_number()) return "a number";
  if (v.is_boolean()) return "a boolean";
  if (v.is_string()) return "a string";
  if (v.is_array()) return "an array";
  if (v.is_object()) return "an object";
  return "null";
}

// The value as the refusal quotes it, cut short for a large array or object.
std::string quoted(const nlohmann::json& v) {
  std::string text = v.dump();
  if (text.size() > 40) text = text.substr(0, 37) + "...";
  return text;
}

}  // namespace

FieldError::FieldError(std::string file, std::string path, std::string reason)
    : std::runtime_error(message(file, path, reason)),
      file_(std::move(file)),
      path_(std::move(path)),
      reason_(std::move(reason)) {}

bool Range::contains(double x) const {
  return (lo_open ? x > lo : x >= lo) && (hi_open ? x < hi : x <= hi);
}

std::string Range::text() const {
  // Built by append: GCC 12 warns (stringop-overflow) on const char* + std::string here.
  const bool no_lo = std::isinf(lo), no_hi = std::isinf(hi);
  std::string t;
  if (no_lo && no_hi) return "any finite number";
  if (no_hi) return t.append(lo_open ? "> " : ">= ").append(number_text(lo));
  if (no_lo) return t.append(hi_open ? "< " : "<= ").append(number_text(hi));
  return t.append(lo_open ? "(" : "[")
      .append(number_text(lo))
      .append(", ")
      .append(number_text(hi))
      .append(hi_open ? ")" : "]");
}

std::string number_text(double x) {
  std::ostringstream o;
  o.precision(10);
  o << x;
  return o.str();
}

std::string nearest_key(const std::string& key, const std::vector<std::string>& known) {
  std::string best;
  std::size_t best_distance = std::string::npos;
  for (const std::string& k : known) {
    // A shortened or lengthened name ("rate" for "rate_hz") counts as one edit.
    const bool prefix = !key.empty() && !k.empty() && (k.starts_with(key) || key.starts_with(k));
    const std::size_t d = prefix ? 1 : edit_distance(key, k);
    if (d < best_distance) best_distance = d, best = k;
  }
  // Near enough to be a typo or a shortened name ("max_wait" for "max_wait_ms"): at most half
  // the longer name, at least 2 edits for short names.
  const std::size_t longer = std::max(key.size(), best.size());
  return best_distance <= std::max<std::size_t>(2, longer / 2) ? best : std::string();
}

// ---- Value ----

Value::Value(const nlohmann::json& value, std::string file, std::string path)
    : value_(&value), file_(std::move(file)), path_(std::move(path)) {}

void Value::fail(const std::string& reason) const {
  throw FieldError(file_, path_.empty() ? "(top level)" : path_, reason);
}

void Value::fail_member(const char* key, const std::string& reason) const {
  throw FieldError(file_, path_.empty() ? key : path_ + "." + key, reason);
}

Object Value::object() const {
  return Object(*this);
}

std::vector<Value> Value::array() const {
  if (!value_->is_array()) fail("expected an array, got " + quoted(*value_));
  std::vector<Value> out;
  out.reserve(value_->size());
  for (std::size_t i = 0; i < value_->size(); ++i)
    out.emplace_back((*value_)[i], file_, path_ + "[" + std::to_string(i) + "]");
  return out;
}

std::vector<Value> Value::array(std::size_t min_size, std::size_t max_size) const {
  std::vector<Value> out = array();
  if (out.size() < min_size || out.size() > max_size) {
    const std::string wanted = min_size == max_size ? std::to_string(min_size)
                               : max_size == std::numeric_limits<std::size_t>::max()
                                   ? "at least " + std::to_string(min_size)
                                   : std::to_string(min_size) + " to " + std::to_string(max_size);
    fail("expected an array of " + wanted + " elements, got " + std::to_string(out.size()));
  }
  return out;
}

bool Value::boolean() const {
  if (!value_->is_boolean()) fail("expected true or false, got " + quoted(*value_));
  return value_->get<bool>();
}

std::string Value::string() const {
  if (!value_->is_string()) fail("expected a string, got " + quoted(*value_));
  return value_->get<std::string>();
}

std::string Value::non_empty_string() const {
  std::string s = string();
  if (s.empty()) fail("expected a non-empty string");
  return s;
}

double Value::number() const {
  // JSON has no NaN or infinity; nlohmann refuses 1e400 while parsing. The check stays for
  // values built in code.
  if (!value_->is_number()) fail("expected a number, got " + quoted(*value_));
  const double d = value_->get<double>();
  if (!std::isfinite(d)) fail("expected a finite number");
  return d;
}

double Value::number(const Range& range) const {
  if (!value_->is_number())
    fail("expected a number in " + range.text() + ", got " + quoted(*value_));
  const double d = value_->get<double>();
  if (!std::isfinite(d) || !range.contains(d))
    fail("expected a number in " + range.text() + ", got " + quoted(*value_));
  return d;
}

std::vector<double> Value::numbers(std::size_t count) const {
  std::vector<double> out;
  for (const Value& v : array(count, count))
    out.push_back(v.number());
  return out;
}

std::int64_t Value::integer(std::int64_t lo, std::int64_t hi) const {
  const auto refuse = [&] {
    fail("expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " +
         quoted(*value_));
  };
  // nlohmann's get<int>() gives 4294967296 as 0 and 2.5 as 2, and a float beyond the integer's
  // range is undefined behaviour: only JSON integers, compared before any cast.
  if (!value_->is_number_integer()) refuse();
  if (value_->is_number_unsigned()) {
    const auto u = value_->get<std::uint64_t>();
    if (hi < 0 || u > static_cast<std::uint64_t>(hi) || std::cmp_less(u, lo)) refuse();
    return static_cast<std::int64_t>(u);
  }
  const auto x = value_->get<std::int64_t>();
  if (x < lo || x > hi) refuse();
  return x;
}

std::uint64_t Value::unsigned_integer(std::uint64_t hi) const {
  if (!value_->is_number_unsigned() || value_->get<std::uint64_t>() > hi)
    fail("expected an integer in [0, " + std::to_string(hi) + "], got " + quoted(*value_));
  return value_->get<std::uint64_t>();
}

// ---- Object ----

Object::Object(const Value& value) : value_(value) {
  if (!value.json().is_object()) value.fail("expected an object, got " + type_name(value.json()));
}

bool Object::has(const char* key) {
  known_.emplace_back(key);
  return value_.json().contains(key);
}

std::optional<Value> Object::find(const char* key) {
  known_.emplace_back(key);
  const auto it = value_.json().find(key);
  if (it == value_.json().end()) return std::nullopt;
  const std::string& p = value_.path();
  return Value(*it, value_.file(), p.empty() ? key : p + "." + key);
}

Value Object::at(const char* key) {
  std::optional<Value> v = find(key);
  if (!v) {
    // A misspelt required key: name the key that was given instead.
    std::string reason = "missing";
    for (const auto& [given, unused] : value_.json().items())
      if (!nearest_key(given, {key}).empty()) {
        reason += " (is " + given + " a typo of it?)";
        break;
      }
    const std::string& p = value_.path();
    throw FieldError(value_.file(), p.empty() ? key : p + "." + key, reason);
  }
  return *v;
}

void Object::known(std::initializer_list<const char*> keys) {
  for (const char* k : keys)
    known_.emplace_back(k);
}

bool Object::get(const char* key, double& out, const Range& range) {
  const std::optional<Value> v = find(key);
  if (v) out = v->number(range);
  return v.has_value();
}

void Object::finish() const {
  for (const auto& [key, v] : value_.json().items()) {
    if (std::find(known_.begin(), known_.end(), key) != known_.end()) continue;
    const std::string& p = value_.path();
    const std::string near = nearest_key(key, known_);
    std::string reason = "unknown key";
    if (!near.empty()) {
      reason += " (did you mean " + near + "?)";
    } else {
      std::vector<std::string> keys = known_;
      std::sort(keys.begin(), keys.end());
      keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
      std::string list;
      for (const std::string& k : keys)
        list += (list.empty() ? "" : ", ") + k;
      reason += " (known keys: " + list + ")";
    }
    throw FieldError(value_.file(), p.empty() ? key : p + "." + key, reason);
  }
}

// ---- Document ----

Document Document::parse(const std::string& text, const std::string& file) {
  try {
    return Document(nlohmann::json::parse(text), file);
  } catch (const nlohmann::json::exception& e) {  // parse_error, or out_of_range for 1e400
    throw FieldError(file, "", std::string("not valid JSON: ") + e.what());
  }
}

Document Document::read(const std::string& path) {
  std::string text;
  try {
    text = read_text_file(path);
  } catch (const FileReadError& e) {
    throw FieldError("", "", e.what());
  }
  return parse(text, path);
}

}  // namespace storetrack::jsonfile
