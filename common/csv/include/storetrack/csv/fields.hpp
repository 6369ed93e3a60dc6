// Fields of one line of the CSV files the project reads and writes. The files are plain: no
// quoting, no embedded separators (every writer in the tree writes numbers and identifiers).
#pragma once

#include <string>
#include <string_view>
#include <vector>

namespace storetrack::csv {

// The cells between separators, as written (not trimmed). A trailing separator is an empty
// last cell, so "a,b," has three cells and a short row cannot look complete; "" has none.
std::vector<std::string> split_fields(std::string_view line, char separator = ',');

// `text` without leading and trailing blanks (space, tab, carriage return).
std::string trim(std::string_view text);

}  // namespace storetrack::csv
