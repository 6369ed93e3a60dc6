// libFuzzer target: the replay directory's index triggers.csv (firmware/capture
// parse_trigger_csv), then the replay source that plays it (ReplayFrameSource over a directory
// with that triggers.csv and one valid frame a.pgm: start(), every frame, one loop further).
// Properties checked (abort when violated), beyond "no crash, no UB":
//  - a refusal is a std::runtime_error naming "triggers.csv line N"; nothing else escapes;
//  - the text is read here independently (docs/unit-config.md, "Replay directory"): the reader
//    accepts exactly the files whose every number is a whole decimal integer in its field's
//    range (trigger_seq and exposure_ns u32, the exposure starts i64 >= 0), and returns those
//    integers (no "12abc" read as 12, no -1 read as 4294967295, no 4294967296 read as 0);
//  - the replay gives each record's sequence, exposure and time stamps as written.
#include <algorithm>
#include <charconv>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "scratch_directory.hpp"
#include "storetrack/capture/replay_frame_source.hpp"

namespace {

namespace capture = storetrack::capture;
namespace fuzz = storetrack::fuzz;

std::vector<std::string_view> split(std::string_view text, char sep) {
  std::vector<std::string_view> out;
  std::size_t start = 0;
  for (;;) {
    const std::size_t end = text.find(sep, start);
    out.push_back(text.substr(start, end == std::string_view::npos ? end : end - start));
    if (end == std::string_view::npos) return out;
    start = end + 1;
  }
}

// A whole decimal integer in [lo, hi], or nothing.
template <typename T>
std::optional<T> whole_integer(std::string_view field, T lo, T hi) {
  T v{};
  const auto [end, ec] = std::from_chars(field.data(), field.data() + field.size(), v);
  if (field.empty() || ec != std::errc() || end != field.data() + field.size() || v < lo || v > hi)
    return std::nullopt;
  return v;
}

int column(const std::vector<std::string_view>& header, std::initializer_list<const char*> names) {
  for (const char* n : names)
    for (std::size_t i = 0; i < header.size(); ++i)
      if (header[i] == n) return static_cast<int>(i);
  return -1;
}

// The records as the documentation defines the file, or nothing for a file to refuse.
std::optional<std::vector<capture::ReplayRecord>> read_as_documented(std::string_view text) {
  std::vector<capture::ReplayRecord> out;
  std::vector<std::string_view> header;
  int c_file = -1, c_seq = -1, c_mono = -1, c_tai = -1, c_exp = -1;
  std::vector<std::string_view> lines = split(text, '\n');
  if (!text.empty() && text.back() == '\n') lines.pop_back();  // no line after the last '\n'
  for (std::string_view line : lines) {
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    if (line.empty() || line[0] == '#') continue;
    const auto f = split(line, ',');
    if (header.empty()) {
      header = f;
      c_file = column(header, {"file"});
      c_seq = column(header, {"trigger_seq"});
      c_mono = column(header, {"exposure_start_mono_ns", "reported_start_mono_ns"});
      c_tai = column(header, {"exposure_start_tai_ns", "reported_start_tai_ns"});
      c_exp = column(header, {"exposure_ns"});
      if (c_file < 0 || c_seq < 0 || c_mono < 0 || c_tai < 0 || c_exp < 0) return std::nullopt;
      continue;
    }
    if (f.size() != header.size()) return std::nullopt;
    const auto at = [&](int c) { return f[static_cast<std::size_t>(c)]; };
    const auto seq = whole_integer<std::uint32_t>(at(c_seq), 0, UINT32_MAX);
    const auto mono = whole_integer<std::int64_t>(at(c_mono), 0, INT64_MAX);
    const auto tai = whole_integer<std::int64_t>(at(c_tai), 0, INT64_MAX);
    const auto exposure = whole_integer<std::uint32_t>(at(c_exp), 0, UINT32_MAX);
    if (!seq || !mono || !tai || !exposure) return std::nullopt;
    out.push_back({std::string(at(c_file)), *seq, *mono, *tai, *exposure});
  }
  return out;
}

// Plays the directory: every record once (at most 64: the index may name a.pgm thousands of
// times), then the loop's first frame.
void replay(const std::string& directory, const std::vector<capture::ReplayRecord>& records) {
  capture::ReplayConfig config;
  config.directory = directory;
  config.loop = true;
  capture::ReplayFrameSource source(config);
  if (source.start() != 0) {
    const bool all_exist =
        !records.empty() && std::all_of(records.begin(), records.end(),
                                        [](const auto& r) { return r.file == "a.pgm"; });
    if (all_exist) std::abort();
    return;
  }
  const std::size_t played = std::min<std::size_t>(records.size(), 64);
  for (std::size_t i = 0; i < played; ++i) {
    storetrack::frame::FrameView f;
    if (source.acquire(f, 0) != 0) std::abort();
    const auto& r = records[i];
    if (f.sequence != r.trigger_seq || f.timestamp_mono_ns != r.exposure_start_mono_ns ||
        source.tai_ns() != r.exposure_start_tai_ns || f.exposure_ns != r.exposure_ns)
      std::abort();
    source.release(f);
  }
  if (played < records.size()) return;
  storetrack::frame::FrameView wrapped;
  if (source.acquire(wrapped, 0) != 0) std::abort();
  source.release(wrapped);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  const auto documented = read_as_documented(text);
  std::vector<capture::ReplayRecord> records;
  try {
    records = capture::parse_trigger_csv(text);
  } catch (const std::runtime_error& e) {
    if (std::string(e.what()).rfind("triggers.csv line ", 0) != 0) std::abort();
    if (documented) std::abort();  // refused a valid file
    return 0;
  }
  if (!documented || documented->size() != records.size()) std::abort();
  for (std::size_t i = 0; i < records.size(); ++i) {
    const auto& a = records[i];
    const auto& b = (*documented)[i];
    if (a.file != b.file || a.trigger_seq != b.trigger_seq ||
        a.exposure_start_mono_ns != b.exposure_start_mono_ns ||
        a.exposure_start_tai_ns != b.exposure_start_tai_ns || a.exposure_ns != b.exposure_ns)
      std::abort();
  }
  fuzz::ScratchDirectory dir("triggers");
  dir.write("triggers.csv", text);
  dir.write("a.pgm", std::string_view("P5\n2 2\n255\n\x01\x02\x03\x04", 15));
  replay(dir.path(), records);
  return 0;
}
