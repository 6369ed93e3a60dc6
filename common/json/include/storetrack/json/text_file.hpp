// The whole of a file as a string: the one implementation every reader of a text file uses.
#pragma once

#include <stdexcept>
#include <string>

namespace storetrack::jsonfile {

class FileReadError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// The file's bytes; throws FileReadError "<path>: cannot open (<errno text>)", "<path>: cannot
/// read (Is a directory)" or "<path>: read error (<errno text>)".
std::string read_text_file(const std::string& path);

}  // namespace storetrack::jsonfile
