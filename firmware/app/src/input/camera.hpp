// Camera: the unit's frame source together with what the capture loop asks of its kind (why a
// start failed, the negotiated size, lost frames, exposure control, recorded time, its stats).
// Each kind (v4l2, replay, sim) answers for itself, so the loop never holds a typed pointer into
// its source to branch on the type; input_factory.cpp is the one place that knows the kinds.
#pragma once

#include <cstdint>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>

#include "simulated_camera.hpp"
#include "storetrack/capture/fault_injecting_frame_source.hpp"
#include "storetrack/frame/frame_source.hpp"

namespace storetrack::unit {

/// What became of a new exposure time (Modbus exposure_us).
enum class ExposureChange {
  kApplied,  ///< the camera exposes as asked (or has no exposure control: stamped only)
  kClamped,  ///< the driver took the closest valid value instead
  kRefused,  ///< the camera keeps its exposure
};

class Camera {
 public:
  /// `backing` is what `source` reads from (the simulator of source sim); it outlives it.
  Camera(std::shared_ptr<const void> backing, std::unique_ptr<frame::FrameSource> source);
  virtual ~Camera();
  Camera(const Camera&) = delete;
  Camera& operator=(const Camera&) = delete;

  // The frame calls go to the outermost source: the fault injector when faults are planned.
  int start() { return source_->start(); }
  int stop() { return source_->stop(); }
  int acquire(frame::FrameView& frame, int timeout_ms) {
    return source_->acquire(frame, timeout_ms);
  }
  int release(const frame::FrameView& frame) { return source_->release(frame); }
  const char* name() const { return source_->name(); }

  /// Puts a fault injector (camera_faults: disconnects, corrupt frames) around the source.
  void inject_faults(const capture::CameraFaultPlan& plan);

  /// Why a call failed with `rc`, in the device's words where it keeps them.
  virtual std::string error(int rc) const;
  /// After start(): the size the device negotiated; unchanged where the kind has no say.
  virtual void started_size(int& /*width*/, int& /*height*/) const {}
  /// What the device noted at start (controls missing, a size changed); empty if nothing.
  virtual std::string notes() const { return {}; }
  /// Frames lost just before `frame`: the device's own count where it keeps one, else the gap
  /// in the source's sequence numbers. Called once per frame, in order.
  virtual std::uint64_t frames_lost_before(const frame::FrameView& frame);
  /// The device's account of its last failure, printed with it; nullptr when it keeps none.
  virtual const char* last_fault() const { return nullptr; }
  /// A new exposure (`applied_us`: what the camera exposes now, when not refused).
  virtual ExposureChange set_exposure_us(std::uint32_t exposure_us, std::uint32_t& applied_us);
  /// The exposure-start TAI the source recorded with the frame last acquired (replay).
  virtual std::optional<std::int64_t> recorded_tai_ns() const { return std::nullopt; }
  /// A source with a clock of its own (sim, replay) keeps TAI - monotonic fixed; others follow
  /// the system clocks.
  virtual std::optional<std::int64_t> fixed_tai_minus_mono_ns() const { return std::nullopt; }
  /// Fault injection of the simulated clock (sim.tai_step_*): the TAI step of the exposure
  /// with this source sequence number.
  virtual std::int64_t tai_step_ns(std::uint32_t /*source_sequence*/) const { return 0; }
  /// A paced simulated source: how far it fell behind its schedule.
  virtual std::optional<SimulatedPacing> pacing() const { return std::nullopt; }
  /// Adds the camera's counters to the stats: `camera` is the stats' "camera" object.
  void add_stats(nlohmann::json& camera, nlohmann::json& stats) const;

 protected:
  virtual void add_device_stats(nlohmann::json& /*camera*/, nlohmann::json& /*stats*/) const {}

 private:
  std::shared_ptr<const void> backing_;
  std::unique_ptr<frame::FrameSource> source_;  // declared after backing_: destroyed first
  const capture::CameraFaultCounters* injected_ = nullptr;
  std::uint32_t last_sequence_ = 0;
  bool have_sequence_ = false;
};

}  // namespace storetrack::unit
