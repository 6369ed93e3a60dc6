// Files a test writes: an empty directory of its own, and bytes from text.
#pragma once

#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace storetrack::test {

/// An empty directory `<temp>/<name>_<pid>` (emptied if it exists): the pid keeps runs of the same
/// test in parallel (ctest -j, several worktrees) out of each other's files.
inline std::filesystem::path fresh_dir(const std::string& name) {
  namespace fs = std::filesystem;
  const fs::path d = fs::temp_directory_path() / (name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

/// The bytes of `s` (embedded NULs included).
inline std::vector<std::uint8_t> bytes_of(const std::string& s) {
  return {s.begin(), s.end()};
}

}  // namespace storetrack::test
