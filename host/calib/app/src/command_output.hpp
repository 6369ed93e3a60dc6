// The end of every storetrack-calib subcommand: its output files written, or the error that
// stopped them, in one wording ("wrote FILE", "error: ...") and one exit code (1: a file not
// written).
#pragma once

#include <functional>
#include <ostream>
#include <string>

namespace storetrack::calibapp {

/// Writes `text` to `path` (truncated first); throws std::runtime_error naming the path.
void write_text(const std::string& path, const std::string& text);

/// Runs `write`; when it throws, prints "error: <what>" to `err` and returns false.
bool wrote_or_reported(std::ostream& err, const std::function<void()>& write);

/// Runs `write` (the command's files): prints "wrote <output>" and returns 0, or prints the
/// error and returns 1.
int write_outputs(const std::string& output, std::ostream& out, std::ostream& err,
                  const std::function<void()>& write);

}  // namespace storetrack::calibapp
