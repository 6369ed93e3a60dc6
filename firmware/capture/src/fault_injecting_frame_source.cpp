#include "storetrack/capture/fault_injecting_frame_source.hpp"

#include <algorithm>
#include <cerrno>
#include <utility>

namespace storetrack::capture {

FaultInjectingFrameSource::FaultInjectingFrameSource(std::unique_ptr<frame::FrameSource> inner,
                                                     CameraFaultPlan plan)
    : inner_(std::move(inner)), plan_(std::move(plan)) {
  std::sort(plan_.disconnect_after_frames.begin(), plan_.disconnect_after_frames.end());
}

int FaultInjectingFrameSource::start() {
  if (!started_once_) {  // the first start is the device's own
    started_once_ = true;
    return inner_->start();
  }
  if (!gone_) return 0;
  if (reopens_to_fail_ > 0) {
    --reopens_to_fail_;
    ++counters_.failed_reopens;
    return -ENODEV;
  }
  gone_ = false;
  discard_outage_frames();
  return 0;
}

// The exposures the camera missed while it was gone: the outage over the trigger period. The
// wrapped source has them (it was not read meanwhile); they never reach the unit.
void FaultInjectingFrameSource::discard_outage_frames() {
  if (plan_.frame_period_ns <= 0) return;
  const std::int64_t missed = (time::monotonic_now_ns() - gone_since_ns_) / plan_.frame_period_ns;
  frame::FrameView f;
  for (std::int64_t k = 0; k < missed && inner_->acquire(f, 1000) == 0; ++k) {
    inner_->release(f);
    ++counters_.frames_lost_disconnected;
  }
}

int FaultInjectingFrameSource::stop() {
  return gone_ ? 0 : inner_->stop();  // a reopen after a disconnect keeps the wrapped source
}

int FaultInjectingFrameSource::acquire(frame::FrameView& frame, int timeout_ms) {
  if (gone_) return -EIO;
  if (next_disconnect_ < plan_.disconnect_after_frames.size() &&
      delivered_ >= plan_.disconnect_after_frames[next_disconnect_]) {
    ++next_disconnect_;
    ++counters_.disconnects;
    gone_ = true;
    gone_since_ns_ = time::monotonic_now_ns();
    reopens_to_fail_ = plan_.failed_reopens;
    return -EIO;
  }
  const int rc = inner_->acquire(frame, timeout_ms);
  if (rc != 0) return rc;
  ++delivered_;
  if (std::find(plan_.corrupt_frames.begin(), plan_.corrupt_frames.end(), delivered_) !=
      plan_.corrupt_frames.end()) {
    inner_->release(frame);
    ++counters_.corrupted;
    return -EBADMSG;
  }
  return 0;
}

int FaultInjectingFrameSource::release(const frame::FrameView& frame) {
  return inner_->release(frame);
}

}  // namespace storetrack::capture
