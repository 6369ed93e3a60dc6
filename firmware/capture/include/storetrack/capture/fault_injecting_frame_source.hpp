// FaultInjectingFrameSource: wraps a FrameSource and injects the camera faults a pylon sees, on a
// schedule of delivered frames, so the unit's recovery is tested end to end without hardware
// (tests/firmware/app; the real driver's faults are vivid's, in the VM rig):
//  - a disconnect (connector, power dip): acquire() fails with -EIO, as V4L2 does on
//    POLLERR/POLLHUP, until the unit reopens the device (stop() + start()); the first
//    `failed_reopens` start() calls fail with -ENODEV. The exposures of the outage are lost:
//    the reopen discards outage / frame_period_ns frames of the wrapped source (which keeps
//    running meanwhile), whatever its own pace.
//  - a corrupted frame (EMI): acquire() returns -EBADMSG, the frame given back.
// Allocation-free after construction, like every FrameSource on the frame path.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "storetrack/frame/frame_source.hpp"

namespace storetrack::capture {

struct CameraFaultPlan {
  /// The device disappears after delivering this many frames (counting from the start), once
  /// per entry, ascending.
  std::vector<std::uint64_t> disconnect_after_frames;
  /// start() calls that fail after each disconnect before the device is back.
  int failed_reopens = 0;
  /// These delivered-frame numbers (1-based) come back as -EBADMSG instead.
  std::vector<std::uint64_t> corrupt_frames;
  /// The trigger period: frames exposed while the camera was gone (0: none discarded).
  std::int64_t frame_period_ns = 0;

  bool empty() const { return disconnect_after_frames.empty() && corrupt_frames.empty(); }
};

struct CameraFaultCounters {
  std::uint64_t disconnects = 0;
  std::uint64_t failed_reopens = 0;
  std::uint64_t corrupted = 0;
  std::uint64_t frames_lost_disconnected = 0;  ///< exposed while the camera was gone
};

class FaultInjectingFrameSource final : public frame::FrameSource {
 public:
  FaultInjectingFrameSource(std::unique_ptr<frame::FrameSource> inner, CameraFaultPlan plan);

  int start() override;
  int stop() override;
  int acquire(frame::FrameView& frame, int timeout_ms) override;
  int release(const frame::FrameView& frame) override;
  const char* name() const override { return inner_->name(); }

  const CameraFaultCounters& counters() const { return counters_; }

 private:
  void discard_outage_frames();

  std::unique_ptr<frame::FrameSource> inner_;
  CameraFaultPlan plan_;
  CameraFaultCounters counters_;
  std::uint64_t delivered_ = 0;  // frames the inner source delivered, corrupted ones included
  std::size_t next_disconnect_ = 0;
  bool gone_ = false;
  std::int64_t gone_since_ns_ = 0;
  bool started_once_ = false;
  int reopens_to_fail_ = 0;
};

}  // namespace storetrack::capture
