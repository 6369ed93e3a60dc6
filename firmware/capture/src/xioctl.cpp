#include "storetrack/capture/xioctl.hpp"

#include <sys/ioctl.h>

#include <cerrno>

namespace storetrack::capture {

int xioctl(int fd, unsigned long request, void* arg) {
  int rc;
  do {
    rc = ioctl(fd, request, arg);
  } while (rc < 0 && errno == EINTR);
  return rc < 0 ? -errno : rc;
}

namespace {
int call_real(void* /*ctx*/, int fd, unsigned long request, void* arg) {
  return xioctl(fd, request, arg);
}
}  // namespace

IoctlOps real_ioctl_ops() {
  return IoctlOps{&call_real, nullptr};
}

}  // namespace storetrack::capture
