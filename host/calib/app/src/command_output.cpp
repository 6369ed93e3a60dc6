#include "command_output.hpp"

#include <exception>
#include <fstream>
#include <stdexcept>

namespace storetrack::calibapp {

void write_text(const std::string& path, const std::string& text) {
  std::ofstream f(path, std::ios::trunc);
  f << text;
  if (!f.flush()) throw std::runtime_error(path + ": write failed");
}

bool wrote_or_reported(std::ostream& err, const std::function<void()>& write) {
  try {
    write();
    return true;
  } catch (const std::exception& e) {
    err << "error: " << e.what() << "\n";
    return false;
  }
}

int write_outputs(const std::string& output, std::ostream& out, std::ostream& err,
                  const std::function<void()>& write) {
  if (!wrote_or_reported(err, write)) return 1;
  out << "wrote " << output << "\n";
  return 0;
}

}  // namespace storetrack::calibapp
