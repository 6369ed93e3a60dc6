#include "storetrack/json/text_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace storetrack::jsonfile {
namespace {

// Closes the descriptor on every way out.
struct Descriptor {
  int fd;
  ~Descriptor() {
    if (fd >= 0) ::close(fd);
  }
};

[[noreturn]] void refuse(const std::string& path, const char* what, int error) {
  throw FileReadError(path + ": " + what + " (" + std::strerror(error) + ")");
}

}  // namespace

// POSIX rather than an ifstream: a stream reads a directory as an empty file and loses errno.
std::string read_text_file(const std::string& path) {
  const Descriptor file{::open(path.c_str(), O_RDONLY | O_CLOEXEC)};
  if (file.fd < 0) refuse(path, "cannot open", errno);
  struct stat info {};
  if (::fstat(file.fd, &info) != 0) refuse(path, "cannot open", errno);
  if (S_ISDIR(info.st_mode)) refuse(path, "cannot read", EISDIR);
  std::string text;
  char buffer[65536];
  for (;;) {
    const ssize_t n = ::read(file.fd, buffer, sizeof buffer);
    if (n == 0) return text;
    if (n < 0) {
      if (errno == EINTR) continue;
      refuse(path, "read error", errno);
    }
    text.append(buffer, static_cast<std::size_t>(n));
  }
}

}  // namespace storetrack::jsonfile
