#include "input/camera.hpp"

#include <cstring>
#include <nlohmann/json.hpp>

namespace storetrack::unit {

Camera::Camera(std::shared_ptr<const void> backing, std::unique_ptr<frame::FrameSource> source)
    : backing_(std::move(backing)), source_(std::move(source)) {}

Camera::~Camera() = default;

void Camera::inject_faults(const capture::CameraFaultPlan& plan) {
  auto faults = std::make_unique<capture::FaultInjectingFrameSource>(std::move(source_), plan);
  injected_ = &faults->counters();
  source_ = std::move(faults);
}

std::string Camera::error(int rc) const {
  return std::strerror(-rc);
}

std::uint64_t Camera::frames_lost_before(const frame::FrameView& frame) {
  std::uint64_t lost = 0;
  if (have_sequence_ && frame.sequence != last_sequence_ + 1)
    lost = static_cast<std::uint32_t>(frame.sequence - last_sequence_ - 1);
  have_sequence_ = true;
  last_sequence_ = frame.sequence;
  return lost;
}

ExposureChange Camera::set_exposure_us(std::uint32_t exposure_us, std::uint32_t& applied_us) {
  applied_us = exposure_us;  // nothing to control: the frames are stamped with it
  return ExposureChange::kApplied;
}

void Camera::add_stats(nlohmann::json& camera, nlohmann::json& stats) const {
  if (injected_ != nullptr) {
    const capture::CameraFaultCounters& f = *injected_;
    camera["injected"] = {{"disconnects", f.disconnects},
                          {"failed_reopens", f.failed_reopens},
                          {"corrupted", f.corrupted},
                          {"frames_lost_disconnected", f.frames_lost_disconnected}};
  }
  add_device_stats(camera, stats);
}

}  // namespace storetrack::unit
