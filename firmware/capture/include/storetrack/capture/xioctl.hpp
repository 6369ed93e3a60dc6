// The one ioctl wrapper of the capture code: retries EINTR, returns 0 or -errno.
#pragma once

namespace storetrack::capture {

/// ioctl(fd, request, arg) retried on EINTR; returns 0 (or the ioctl's non-negative result)
/// or -errno. Never throws, never allocates.
int xioctl(int fd, unsigned long request, void* arg);

/// Indirection used by the V4L2 code so that the pure negotiation logic can be tested against
/// a fake device: ctx is the implementation's state (nullptr for the real xioctl).
struct IoctlOps {
  int (*call)(void* ctx, int fd, unsigned long request, void* arg) = nullptr;
  void* ctx = nullptr;
  int operator()(int fd, unsigned long request, void* arg) const {
    return call(ctx, fd, request, arg);
  }
};

/// IoctlOps that calls xioctl().
IoctlOps real_ioctl_ops();

}  // namespace storetrack::capture
