#include "storetrack/csv/fields.hpp"

namespace storetrack::csv {

std::vector<std::string> split_fields(std::string_view line, char separator) {
  std::vector<std::string> cells;
  if (line.empty()) return cells;
  std::size_t begin = 0;
  while (true) {
    const std::size_t end = line.find(separator, begin);
    if (end == std::string_view::npos) {
      cells.emplace_back(line.substr(begin));
      return cells;
    }
    cells.emplace_back(line.substr(begin, end - begin));
    begin = end + 1;
  }
}

std::string trim(std::string_view text) {
  constexpr std::string_view kBlanks = " \t\r";
  const std::size_t begin = text.find_first_not_of(kBlanks);
  if (begin == std::string_view::npos) return {};
  return std::string(text.substr(begin, text.find_last_not_of(kBlanks) - begin + 1));
}

}  // namespace storetrack::csv
