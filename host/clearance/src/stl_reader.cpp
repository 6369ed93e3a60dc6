#include <cctype>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <span>
#include <unordered_map>

#include "mesh_build.hpp"
#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/clearance/mesh.hpp"
#include "storetrack/json/text_file.hpp"

namespace storetrack::clearance {
namespace {

using geometry::Vec3;

constexpr std::size_t kBinaryHeaderBytes = 84;    // 80-byte comment + uint32 triangle count
constexpr std::size_t kBinaryTriangleBytes = 50;  // normal, 3 vertices (12 float32), uint16

bool printable_text(const std::string& bytes) {
  for (const char c : bytes) {
    const auto u = static_cast<unsigned char>(c);
    if (u < 0x20 && c != '\n' && c != '\r' && c != '\t' && c != '\f' && c != '\v') return false;
    if (u == 0x7f) return false;
  }
  return true;
}

bool starts_with_solid(const std::string& bytes) {
  std::size_t i = 0;
  while (i < bytes.size() && std::isspace(static_cast<unsigned char>(bytes[i])))
    ++i;
  return bytes.compare(i, 5, "solid") == 0;
}

TriangleMesh parse_binary(const std::string& bytes, const std::string& file) {
  const std::span<const std::uint8_t> data(reinterpret_cast<const std::uint8_t*>(bytes.data()),
                                           bytes.size());
  bytes::LittleEndianReader in(data);
  in.skip(80);
  const std::uint32_t count = in.get_u32();
  MeshBuilder builder(file);
  for (std::uint32_t t = 0; t < count; ++t) {
    in.skip(12);  // the stored normal: often zero or stale in CAD exports, recomputed when needed
    std::array<Vec3, 3> v;
    for (Vec3& p : v)
      for (int k = 0; k < 3; ++k)
        p(k) = static_cast<double>(in.get_f32());
    in.skip(2);  // attribute byte count
    builder.add(v);
  }
  return builder.finish();
}

/// Whitespace-separated words of ASCII STL, with the line each came from.
class Words {
 public:
  explicit Words(const std::string& text) : text_(text) {}
  bool next(std::string& word) {
    while (pos_ < text_.size() && std::isspace(static_cast<unsigned char>(text_[pos_]))) {
      if (text_[pos_] == '\n') ++line_;
      ++pos_;
    }
    if (pos_ >= text_.size()) return false;
    const std::size_t start = pos_;
    while (pos_ < text_.size() && !std::isspace(static_cast<unsigned char>(text_[pos_])))
      ++pos_;
    word.assign(text_, start, pos_ - start);
    return true;
  }
  void skip_line() {
    while (pos_ < text_.size() && text_[pos_] != '\n')
      ++pos_;
  }
  int line() const { return line_; }

 private:
  const std::string& text_;
  std::size_t pos_ = 0;
  int line_ = 1;
};

class AsciiParser {
 public:
  AsciiParser(const std::string& text, const std::string& file)
      : words_(text), file_(file), builder_(file) {}

  TriangleMesh parse() {
    expect("solid");
    words_.skip_line();  // the solid's name, any text
    std::string w;
    while (words_.next(w)) {
      if (w == "facet") {
        facet();
      } else if (w == "endsolid") {
        words_.skip_line();
        if (!words_.next(w)) break;
        if (w != "solid") refuse("expected 'solid' or the end of the file, found '" + w + "'");
        words_.skip_line();
      } else {
        refuse("expected 'facet' or 'endsolid', found '" + w + "'");
      }
    }
    return builder_.finish();
  }

 private:
  void facet() {
    expect("normal");
    for (int k = 0; k < 3; ++k)
      number();  // the stored normal is not used
    expect("outer");
    expect("loop");
    std::array<Vec3, 3> v;
    for (Vec3& p : v) {
      expect("vertex");
      for (int k = 0; k < 3; ++k)
        p(k) = number();
    }
    expect("endloop");
    expect("endfacet");
    builder_.add(v);
  }

  void expect(const char* keyword) {
    std::string w;
    if (!words_.next(w))
      refuse(std::string("expected '") + keyword + "', found the end of the file");
    if (w != keyword) refuse(std::string("expected '") + keyword + "', found '" + w + "'");
  }

  // strtod also takes "nan" and "inf": those are refused as non-finite vertices with the
  // triangle named, like the same values in a binary file.
  double number() {
    std::string w;
    if (!words_.next(w)) refuse("expected a number, found the end of the file");
    char* end = nullptr;
    const double x = std::strtod(w.c_str(), &end);
    if (end != w.c_str() + w.size() || w.empty()) refuse("expected a number, found '" + w + "'");
    return x;
  }

  [[noreturn]] void refuse(const std::string& reason) const {
    throw MeshError(file_, builder_.size(),
                    "line " + std::to_string(words_.line()) + ": " + reason);
  }

  Words words_;
  const std::string& file_;
  MeshBuilder builder_;
};

}  // namespace

MeshError::MeshError(std::string file, std::optional<std::int64_t> triangle, std::string reason)
    : std::runtime_error(file + ": " +
                         (triangle ? "triangle " + std::to_string(*triangle) + ": " : "") + reason),
      file_(std::move(file)),
      triangle_(triangle),
      reason_(std::move(reason)) {}

// Binary when the size is exactly what the header's triangle count states (a binary header may
// itself start with "solid", as some exporters write it); ASCII when the file starts with
// "solid" and is all text; otherwise a binary file of the wrong size, refused as truncated.
TriangleMesh parse_stl(const std::string& bytes, const std::string& file) {
  if (bytes.size() >= kBinaryHeaderBytes) {
    bytes::LittleEndianReader in(std::span<const std::uint8_t>(
        reinterpret_cast<const std::uint8_t*>(bytes.data()), kBinaryHeaderBytes));
    in.skip(80);
    const std::uint64_t count = in.get_u32();
    const std::uint64_t expected = kBinaryHeaderBytes + kBinaryTriangleBytes * count;
    if (expected == bytes.size()) return parse_binary(bytes, file);
    if (starts_with_solid(bytes) && printable_text(bytes)) return AsciiParser(bytes, file).parse();
    const std::uint64_t complete = (bytes.size() - kBinaryHeaderBytes) / kBinaryTriangleBytes;
    if (expected > bytes.size())
      throw MeshError(file, static_cast<std::int64_t>(complete),
                      "binary STL truncated: its header states " + std::to_string(count) +
                          " triangles (" + std::to_string(expected) + " bytes), the file has " +
                          std::to_string(bytes.size()) + " bytes; this triangle is incomplete");
    throw MeshError(file, std::nullopt,
                    "binary STL of the wrong size: its header states " + std::to_string(count) +
                        " triangles (" + std::to_string(expected) + " bytes), the file has " +
                        std::to_string(bytes.size()) + " bytes");
  }
  if (starts_with_solid(bytes) && printable_text(bytes)) return AsciiParser(bytes, file).parse();
  throw MeshError(file, std::nullopt,
                  "neither ASCII STL (starts with 'solid') nor binary STL (" +
                      std::to_string(bytes.size()) + " bytes, shorter than the 84-byte header)");
}

TriangleMesh read_stl(const std::string& path) {
  return parse_stl(jsonfile::read_text_file(path), path);
}

}  // namespace storetrack::clearance
