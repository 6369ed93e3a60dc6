// The one strict reader of the project's JSON files. Every refusal is a FieldError naming the
// file, the field's path ("aligner.max_wait_ms", "marks[2].id") and the reason; an unknown key is
// refused with the nearest known one ("did you mean max_wait_ms?"), a value of the wrong type or
// shape is refused, an integer field takes only JSON integers (2.5, 1e3 and true are refused, and
// so is a value outside the field's range, stated as the range the program really accepts).
//
//   Document doc = Document::parse(read_text_file(path), path);
//   Object top = doc.root().object();
//   if (auto a = top.find("aligner")) {
//     Object aligner = a->object();
//     aligner.get("max_pending", config.max_pending, 1, 4096);
//     aligner.finish();  // refuses the keys no get/find/has asked for
//   }
//   top.finish();
#pragma once

#include <concepts>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace storetrack::jsonfile {

/// A refused field: what() is "<file>: <path>: <reason>" ("<file>: <reason>" for the document).
class FieldError : public std::runtime_error {
 public:
  FieldError(std::string file, std::string path, std::string reason);
  const std::string& file() const noexcept { return file_; }
  const std::string& path() const noexcept { return path_; }
  const std::string& reason() const noexcept { return reason_; }

 private:
  std::string file_;
  std::string path_;
  std::string reason_;
};

/// A range of numbers, closed unless told; text() is "[0, 1000]", "(0, 60000]", ">= 0".
struct Range {
  double lo = -std::numeric_limits<double>::infinity();
  double hi = std::numeric_limits<double>::infinity();
  bool lo_open = false;
  bool hi_open = false;

  static Range closed(double lo, double hi) { return {lo, hi, false, false}; }
  static Range above(double lo) { return {lo, std::numeric_limits<double>::infinity(), true}; }
  static Range at_least(double lo) { return {lo, std::numeric_limits<double>::infinity()}; }
  bool contains(double x) const;
  std::string text() const;
};

/// A number as a message shows it: 1e+300, not 300 digits; 0.001, not 0.001000.
std::string number_text(double x);

/// The known key nearest to `key` by edit distance (a swap of two letters counts one), or ""
/// when none is near enough to be a typo of it.
std::string nearest_key(const std::string& key, const std::vector<std::string>& known);

class Object;

/// One JSON value and where it lies (file and path). Refers into its Document.
class Value {
 public:
  Value(const nlohmann::json& value, std::string file, std::string path);

  const nlohmann::json& json() const { return *value_; }
  const std::string& file() const { return file_; }
  const std::string& path() const { return path_; }
  [[noreturn]] void fail(const std::string& reason) const;
  /// Refuses this object's member `key` (present or not): "<path>.<key>: <reason>".
  [[noreturn]] void fail_member(const char* key, const std::string& reason) const;

  Object object() const;
  std::vector<Value> array() const;
  std::vector<Value> array(std::size_t min_size, std::size_t max_size) const;
  bool boolean() const;
  std::string string() const;
  std::string non_empty_string() const;
  double number() const;  // finite
  double number(const Range& range) const;
  std::vector<double> numbers(std::size_t count) const;  // exactly `count` finite numbers
  std::int64_t integer(std::int64_t lo, std::int64_t hi) const;
  std::uint64_t unsigned_integer(std::uint64_t hi) const;  // [0, hi]

  /// Read by the C++ type: bool, std::string, an integer type (its whole range), a floating type
  /// (finite), a std::vector of those.
  template <typename T>
  T as() const;

 private:
  const nlohmann::json* value_;
  std::string file_;
  std::string path_;
};

/// A JSON object whose keys are read by name; finish() refuses every key no one asked for.
class Object {
 public:
  explicit Object(const Value& value);  // refuses a value that is not an object

  const Value& value() const { return value_; }
  [[noreturn]] void fail(const std::string& reason) const { value_.fail(reason); }

  bool has(const char* key);                            // `key` becomes known
  std::optional<Value> find(const char* key);           // `key` becomes known
  Value at(const char* key);                            // refuses a missing key
  void known(std::initializer_list<const char*> keys);  // accepted without being read here

  /// An optional field into `out` (left as it was when absent); true when present.
  template <typename T>
  bool get(const char* key, T& out);
  bool get(const char* key, double& out, const Range& range);
  template <std::integral T>
  bool get(const char* key, T& out, std::int64_t lo, std::int64_t hi);

  /// Refuses the first key that is not known, naming the nearest known key.
  void finish() const;

 private:
  Value value_;
  std::vector<std::string> known_;
};

/// A parsed file: refuses text that is not JSON (and numbers beyond double) with the file named.
class Document {
 public:
  static Document parse(const std::string& text, const std::string& file);
  /// read_text_file + parse; a file that cannot be read is refused as a FieldError too.
  static Document read(const std::string& path);

  Value root() const { return Value(root_, file_, ""); }

 private:
  Document(nlohmann::json root, std::string file)
      : root_(std::move(root)), file_(std::move(file)) {}
  nlohmann::json root_;
  std::string file_;
};

// ---- templates ----

template <typename T>
T Value::as() const {
  if constexpr (std::is_same_v<T, bool>) {
    return boolean();
  } else if constexpr (std::is_same_v<T, std::string>) {
    return string();
  } else if constexpr (std::is_integral_v<T> && std::is_unsigned_v<T>) {
    return static_cast<T>(unsigned_integer(std::numeric_limits<T>::max()));
  } else if constexpr (std::is_integral_v<T>) {
    return static_cast<T>(integer(std::numeric_limits<T>::min(), std::numeric_limits<T>::max()));
  } else if constexpr (std::is_floating_point_v<T>) {
    return static_cast<T>(number());
  } else {
    using Element = typename T::value_type;
    static_assert(std::is_same_v<T, std::vector<Element>>, "unsupported type");
    T out;
    for (const Value& v : array())
      out.push_back(v.as<Element>());
    return out;
  }
}

template <typename T>
bool Object::get(const char* key, T& out) {
  const std::optional<Value> v = find(key);
  if (v) out = v->as<T>();
  return v.has_value();
}

template <std::integral T>
bool Object::get(const char* key, T& out, std::int64_t lo, std::int64_t hi) {
  const std::optional<Value> v = find(key);
  if (v) out = static_cast<T>(v->integer(lo, hi));
  return v.has_value();
}

}  // namespace storetrack::jsonfile
