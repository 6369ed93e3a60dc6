// libFuzzer target: the initial mark positions reader (host/app parse_initial_marks, the
// installation survey {"marks": [{"id": 0, "p_w_m": [x, y, z]}, ...]}) on arbitrary text.
// Properties checked (abort when violated), beyond "no crash, no UB":
//  - a refusal is a HostConfigError naming the origin; no other exception escapes;
//  - an accepted file gives one finite position per mark entry (no entry silently merged into
//    another: ids are unique) and every id is the integer the file wrote (no wrap, no truncated
//    2.5).
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include <nlohmann/json.hpp>

#include "host_config.hpp"

namespace app = storetrack::hostapp;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  std::map<int, storetrack::geometry::Vec3> marks;
  try {
    marks = app::parse_initial_marks(text, "fuzz.json");
  } catch (const app::HostConfigError& e) {
    if (std::string(e.what()).rfind("fuzz.json: ", 0) != 0) std::abort();
    return 0;
  }
  // Read independently: the entries as written.
  const auto entries = nlohmann::json::parse(text).at("marks");
  if (entries.size() != marks.size()) std::abort();
  for (const auto& m : entries) {
    const auto& id = m.at("id");
    if (!id.is_number_integer()) std::abort();
    const std::int64_t written = id.is_number_unsigned() && id.get<std::uint64_t>() > INT64_MAX
                                     ? INT64_MAX
                                     : id.get<std::int64_t>();
    const auto it = marks.find(static_cast<int>(written));
    if (written < INT32_MIN || written > INT32_MAX || it == marks.end()) std::abort();
    const auto p = m.at("p_w_m").get<std::vector<double>>();
    if (!it->second.allFinite() || it->second != storetrack::geometry::Vec3(p[0], p[1], p[2]))
      std::abort();
  }
  return 0;
}
