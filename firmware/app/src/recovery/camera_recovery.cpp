#include "recovery/camera_recovery.hpp"

#include <algorithm>
#include <cstdio>
#include <cstring>

namespace storetrack::unit {

void CameraRecovery::configure(int first_ms, int max_ms) {
  first_backoff_ns_ = std::int64_t{first_ms} * 1'000'000;
  max_backoff_ns_ = std::int64_t{max_ms} * 1'000'000;
  backoff_ns_ = first_backoff_ns_;
}

void CameraRecovery::failed(Camera& camera, int rc, time::MonotonicNs now) {
  ++counters_.failures;
  const char* fault = camera.last_fault();
  std::fprintf(stderr, "storetrack-unit: camera %s failed (%s%s%s); reopening in %lld ms\n",
               camera.name(), std::strerror(-rc), fault ? ": " : "", fault ? fault : "",
               static_cast<long long>(backoff_ns_ / 1'000'000));
  camera.stop();
  down_ = true;
  down_since_ns_ = now;
  next_try_ns_ = now + backoff_ns_;
}

int CameraRecovery::wait_ms(time::MonotonicNs now) const {
  if (now >= next_try_ns_) return 0;
  return static_cast<int>(std::clamp<std::int64_t>((next_try_ns_ - now) / 1'000'000, 1, 10));
}

bool CameraRecovery::try_restart(Camera& camera, time::MonotonicNs now) {
  if (camera.start() < 0) {
    ++counters_.reopen_failures;
    backoff_ns_ = std::min(max_backoff_ns_, backoff_ns_ * 2);
    next_try_ns_ = now + backoff_ns_;
    return false;
  }
  down_ = false;
  ++counters_.reopens;
  counters_.down_s += static_cast<double>(now - down_since_ns_) * 1e-9;
  backoff_ns_ = first_backoff_ns_;
  std::fprintf(stderr, "storetrack-unit: camera %s back after %.3f s\n", camera.name(),
               static_cast<double>(now - down_since_ns_) * 1e-9);
  return true;
}

void CameraRecovery::close(time::MonotonicNs now) {
  if (down_) counters_.down_s += static_cast<double>(now - down_since_ns_) * 1e-9;
}

}  // namespace storetrack::unit
