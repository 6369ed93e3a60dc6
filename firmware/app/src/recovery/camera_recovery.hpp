// CameraRecovery: a camera that is gone (V4L2: POLLERR/POLLHUP, a failed VIDIOC_DQBUF, every
// buffer lost) is stopped and started again later, at doubling intervals up to a maximum. The
// trigger keeps running meanwhile (a gpio master drives the whole rig's exposures) and health
// keeps going out with the camera-error bit set.
#pragma once

#include <cstdint>

#include "input/camera.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::unit {

struct CameraRecoveryCounters {
  std::uint64_t failures = 0;         ///< the device was gone (POLLERR, DQBUF, no buffer)
  std::uint64_t reopens = 0;          ///< ... and came back after a reopen
  std::uint64_t reopen_failures = 0;  ///< tries that did not bring it back
  double down_s = 0;                  ///< time without a camera, in all
};

class CameraRecovery {
 public:
  /// The first wait after a failure and the longest, in ms (camera_reopen_first_ms, _max_ms).
  void configure(int first_ms, int max_ms);
  bool down() const { return down_; }
  /// The camera failed with `rc`: said on stderr, stopped, to be started again after the wait.
  void failed(Camera& camera, int rc, time::MonotonicNs now);
  /// While down: how long to wait before the next try (1..10 ms, so the loop goes on), or 0
  /// when a try is due.
  int wait_ms(time::MonotonicNs now) const;
  /// A try: true when the camera runs again (the wait starts over), else the wait doubles.
  bool try_restart(Camera& camera, time::MonotonicNs now);
  /// At the end of the run: an outage still open counts until `now`.
  void close(time::MonotonicNs now);
  const CameraRecoveryCounters& counters() const { return counters_; }

 private:
  time::MonotonicNs first_backoff_ns_ = 0;
  time::MonotonicNs max_backoff_ns_ = 0;
  time::MonotonicNs backoff_ns_ = 0;
  bool down_ = false;
  time::MonotonicNs down_since_ns_ = 0;
  time::MonotonicNs next_try_ns_ = 0;
  CameraRecoveryCounters counters_;
};

}  // namespace storetrack::unit
