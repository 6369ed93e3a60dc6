#include "input/input_factory.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <nlohmann/json.hpp>

#include "exit_codes.hpp"
#include "storetrack/capture/replay_frame_source.hpp"
#include "storetrack/capture/v4l2_frame_source.hpp"
#include "storetrack/trigger/gpio_trigger.hpp"
#include "storetrack/trigger/sim_trigger.hpp"

namespace storetrack::unit {
namespace {

// --- cameras -----------------------------------------------------------------------------------

class V4l2Camera final : public Camera {
 public:
  V4l2Camera(std::unique_ptr<capture::V4L2FrameSource> device, const V4l2SourceConfig& config)
      : V4l2Camera(*device, std::move(device), config) {}
  std::string error(int /*rc*/) const override { return device_.error(); }
  void started_size(int& width, int& height) const override {
    width = device_.format().width;
    height = device_.format().height;
  }
  std::string notes() const override { return device_.notes(); }
  // The driver counts its sequence gaps itself (a reopened device starts its sequence again).
  std::uint64_t frames_lost_before(const frame::FrameView& /*frame*/) override {
    const std::uint64_t dropped = device_.stats().dropped;
    const std::uint64_t lost = dropped - dropped_seen_;
    dropped_seen_ = dropped;
    return lost;
  }
  const char* last_fault() const override { return device_.last_fault(); }
  // VIDIOC_S_CTRL may take the closest valid value instead of refusing: the unit reports and
  // stamps what the camera does, not what was asked.
  ExposureChange set_exposure_us(std::uint32_t exposure_us, std::uint32_t& applied_us) override {
    if (config_.exposure_control.empty()) return Camera::set_exposure_us(exposure_us, applied_us);
    const double unit_us = config_.exposure_control_unit_us;
    const auto wanted = static_cast<std::int32_t>(std::lround(exposure_us / unit_us));
    std::int32_t applied = wanted;
    if (device_.set_control(config_.exposure_control, wanted, &applied) < 0)
      return ExposureChange::kRefused;
    applied_us = applied == wanted ? exposure_us
                                   : static_cast<std::uint32_t>(std::clamp<long>(
                                         std::lround(applied * unit_us), 1, 65535));
    device_.set_reported_exposure_ns(applied_us * 1000u);
    return applied == wanted ? ExposureChange::kApplied : ExposureChange::kClamped;
  }

 protected:
  void add_device_stats(nlohmann::json& camera, nlohmann::json& stats) const override {
    const capture::V4L2Stats v = device_.stats();
    camera["v4l2"] = {{"error_buffers", v.error_buffers},
                      {"short_buffers", v.short_buffers},
                      {"requeue_errors", v.requeue_errors},
                      {"sequence_resets", v.sequence_resets},
                      {"timeouts", v.timeouts}};
    stats["v4l2"] = {{"device", config_.device.device},
                     {"fourcc", capture::fourcc_to_string(device_.format().fourcc)},
                     {"width", device_.format().width},
                     {"height", device_.format().height},
                     {"frames", v.frames},
                     {"dropped", v.dropped},
                     {"error_buffers", v.error_buffers},
                     {"timeouts", v.timeouts},
                     {"notes", device_.notes()}};
  }

 private:
  // The base owns the device (behind a fault injector, maybe); moved only once bound here.
  V4l2Camera(capture::V4L2FrameSource& device, std::unique_ptr<capture::V4L2FrameSource>&& owned,
             const V4l2SourceConfig& config)
      : Camera(nullptr, std::move(owned)), device_(device), config_(config) {}

  capture::V4L2FrameSource& device_;
  V4l2SourceConfig config_;
  std::uint64_t dropped_seen_ = 0;
};

class ReplayCamera final : public Camera {
 public:
  explicit ReplayCamera(std::unique_ptr<capture::ReplayFrameSource> replay)
      : ReplayCamera(*replay, std::move(replay)) {}
  std::string error(int /*rc*/) const override { return replay_.error(); }
  std::optional<std::int64_t> recorded_tai_ns() const override { return replay_.tai_ns(); }
  // The recording's own times stand; the offset is never read from this unit's clocks.
  std::optional<std::int64_t> fixed_tai_minus_mono_ns() const override { return 0; }

 private:
  ReplayCamera(capture::ReplayFrameSource& replay,
               std::unique_ptr<capture::ReplayFrameSource>&& owned)
      : Camera(nullptr, std::move(owned)), replay_(replay) {}

  capture::ReplayFrameSource& replay_;  // owned by the base
};

class SimCamera final : public Camera {
 public:
  SimCamera(SimulatedCamera camera, const SimSourceConfig& config)
      : Camera(std::move(camera.simulation), std::move(camera.source)),
        tai_minus_mono_ns_(camera.tai_minus_mono_ns),
        first_trigger_seq_(camera.first_trigger_seq),
        pacing_(std::move(camera.pacing)),
        config_(config) {}
  std::optional<std::int64_t> fixed_tai_minus_mono_ns() const override {
    return tai_minus_mono_ns_;
  }
  std::int64_t tai_step_ns(std::uint32_t source_sequence) const override {
    if (config_.tai_step_ns == 0) return 0;
    const auto k = static_cast<std::int64_t>(source_sequence - first_trigger_seq_);
    return k >= config_.tai_step_from && k < config_.tai_step_to ? config_.tai_step_ns : 0;
  }
  std::optional<SimulatedPacing> pacing() const override {
    if (!pacing_) return std::nullopt;
    return pacing_();
  }

 private:
  std::int64_t tai_minus_mono_ns_;
  std::uint32_t first_trigger_seq_;
  std::function<SimulatedPacing()> pacing_;  // set when paced (realtime)
  SimSourceConfig config_;
};

// --- triggers ----------------------------------------------------------------------------------

class SimTrigger final : public Trigger {
 public:
  explicit SimTrigger(std::unique_ptr<trigger::SimTriggerLine> line)
      : SimTrigger(*line, std::move(line)) {}
  bool follows_frames() const override { return true; }
  void set_origin(time::MonotonicNs edge_ns) override { sim_.set_origin(edge_ns); }
  void advance_to(time::MonotonicNs t_ns) override { sim_.advance_to(t_ns); }

 private:
  SimTrigger(trigger::SimTriggerLine& sim, std::unique_ptr<trigger::SimTriggerLine>&& owned)
      : Trigger(std::move(owned)), sim_(sim) {}

  trigger::SimTriggerLine& sim_;  // owned by the base
};

// The generator never drives a pulse later than half this unit's phase tolerance after its grid
// time (at most period / 8): the pulse's stamp must land inside the tolerance, or the pairer
// would call a real exposure an extra edge.
trigger::GpioMasterConfig master_config(const TriggerConfig& trigger, double rate_hz,
                                        std::int64_t width_ns) {
  trigger::GpioMasterConfig mc;
  mc.chip = trigger.chip;
  mc.lines = trigger.lines;
  mc.active_low = trigger.active_low;
  mc.rate_hz = rate_hz;
  mc.pulse_width_ns = width_ns;
  const auto period = static_cast<std::int64_t>(std::llround(1e9 / rate_hz));
  const std::int64_t tolerance =
      trigger.edge_phase_tolerance_ns > 0 ? trigger.edge_phase_tolerance_ns : period / 4;
  mc.max_late_ns = std::max<std::int64_t>(1, std::min(period / 8, tolerance / 2));
  return mc;
}

class GpioMaster final : public Trigger {
 public:
  GpioMaster(std::unique_ptr<trigger::GpioMasterTrigger> line, const TriggerConfig& config)
      : Trigger(std::move(line)), config_(config) {}
  // The generator is restarted with the new rate; if the new one does not start, the old one
  // is started again (the rig must keep its trigger).
  TriggerChange change(double rate_hz, std::int64_t width_ns) override {
    const trigger::GpioMasterConfig mc = master_config(config_, rate_hz, width_ns);
    if (trigger::validate(mc, nullptr) < 0) return TriggerChange::kInvalid;
    line_->stop();
    auto fresh = std::make_unique<trigger::GpioMasterTrigger>(mc);
    if (fresh->start() != 0) {
      std::fprintf(stderr,
                   "storetrack-unit: trigger %.0f Hz / %lld ns not started (%s); "
                   "the previous trigger goes on\n",
                   rate_hz, static_cast<long long>(width_ns), fresh->error().c_str());
      if (line_->start() != 0) {
        down_ = true;
        retry_ns_ = time::monotonic_now_ns() + time::kNsPerSecond;
        return TriggerChange::kPreviousNotRunning;
      }
      return TriggerChange::kKeptPrevious;
    }
    line_ = std::move(fresh);
    return TriggerChange::kApplied;
  }
  TriggerRetry retry_stopped() override {
    if (!down_) return TriggerRetry::kNothingToDo;
    const time::MonotonicNs now = time::monotonic_now_ns();
    if (now < retry_ns_) return TriggerRetry::kNothingToDo;
    retry_ns_ = now + time::kNsPerSecond;
    if (line_->start() != 0) return TriggerRetry::kStillDown;
    down_ = false;
    std::fprintf(stderr, "storetrack-unit: trigger %s running again\n", line_->name());
    return TriggerRetry::kRunning;
  }
  std::uint64_t new_pulse_errors() override {
    const std::uint64_t line_errors = line_->stats().line_errors;
    const std::uint64_t fresh =
        line_errors > line_errors_seen_ ? line_errors - line_errors_seen_ : 0;
    line_errors_seen_ = line_errors;
    return fresh;
  }

 private:
  TriggerConfig config_;  // the lines; rate and width come with each change
  bool down_ = false;     // not started again after a failed change: retried
  time::MonotonicNs retry_ns_ = 0;
  std::uint64_t line_errors_seen_ = 0;  // at the last new_pulse_errors()
};

}  // namespace

int InputFactory::make_camera(std::unique_ptr<Camera>& camera, CameraFacts& facts,
                              std::string& error) {
  facts.width = config_.v4l2.device.width;
  facts.height = config_.v4l2.device.height;
  try {
    switch (config_.source) {
      case SourceType::kSim: {
        if (!simulated_) {
          error =
              "source sim: this program was built without the simulated mode "
              "(it links no storetrack_unit_sim)";
          return kExitUsage;
        }
        SimulatedCamera sim;
        if (!simulated_(config_.sim, sim, error)) return kExitUsage;
        if (config_.unit_id < 0) config_.unit_id = sim.unit_id;
        if (config_.camera_id < 0) config_.camera_id = sim.camera_id;
        facts.width = sim.width;
        facts.height = sim.height;
        if (config_.clock_state == "auto") facts.clock_state = sim.clock_state;
        facts.clock_sigma_ns = sim.clock_sigma_ns;
        if (config_.trigger.mode == TriggerMode::kSim) config_.trigger.rate_hz = sim.frame_rate_hz;
        camera = std::make_unique<SimCamera>(std::move(sim), config_.sim);
        break;
      }
      case SourceType::kReplay: {
        capture::ReplayConfig rc;
        rc.directory = config_.replay.directory;
        rc.rate_hz = config_.replay.rate_hz;
        rc.loop = config_.replay.loop;
        rc.default_period_ns =
            static_cast<std::int64_t>(std::llround(1e9 / config_.trigger.rate_hz));
        rc.default_exposure_ns = config_.exposure_us * 1000u;
        camera = std::make_unique<ReplayCamera>(std::make_unique<capture::ReplayFrameSource>(rc));
        break;
      }
      case SourceType::kV4l2: {
        capture::V4L2Config vc = config_.v4l2.device;
        vc.exposure_ns = config_.exposure_us * 1000u;
        camera = std::make_unique<V4l2Camera>(std::make_unique<capture::V4L2FrameSource>(vc),
                                              config_.v4l2);
        break;
      }
      case SourceType::kNone:
        break;
    }
  } catch (const std::exception& e) {
    error = std::string("source: ") + e.what();
    return kExitUsage;
  }
  if (camera && !config_.camera_faults.empty()) {
    capture::CameraFaultPlan plan = config_.camera_faults;
    const double rate_hz =
        config_.source == SourceType::kSim && config_.sim.realtime && config_.sim.pace_hz > 0
            ? config_.sim.pace_hz
            : config_.trigger.rate_hz;
    plan.frame_period_ns = rate_hz > 0 ? std::llround(1e9 / rate_hz) : 0;
    camera->inject_faults(plan);
  }
  return kExitOk;
}

int InputFactory::make_trigger(std::int64_t period_ns, std::unique_ptr<Trigger>& trigger,
                               std::string& error) {
  const TriggerConfig& tc = config_.trigger;
  switch (tc.mode) {
    case TriggerMode::kNone:
      break;
    case TriggerMode::kSim: {
      trigger::SimTriggerConfig sc;
      sc.period_ns = period_ns;
      sc.jitter_ns = tc.sim_jitter_ns;
      sc.drop_every = tc.sim_drop_every;
      sc.extra_every = tc.sim_extra_every;
      sc.read_error_every = tc.sim_read_error_every;
      trigger = std::make_unique<SimTrigger>(std::make_unique<trigger::SimTriggerLine>(sc));
      break;
    }
    case TriggerMode::kGpioMaster: {
      auto t = std::make_unique<trigger::GpioMasterTrigger>(
          master_config(tc, tc.rate_hz, tc.pulse_width_ns));
      if (t->start() < 0) {
        error = "trigger: " + t->error();
        return kExitStartFailure;
      }
      trigger = std::make_unique<GpioMaster>(std::move(t), tc);
      break;
    }
    case TriggerMode::kGpioSlave: {
      trigger::GpioSlaveConfig sc;
      sc.chip = tc.chip;
      sc.line = tc.line;
      sc.active_low = tc.active_low;
      auto t = std::make_unique<trigger::GpioSlaveTrigger>(sc);
      if (t->start() < 0) {
        error = "trigger: " + t->error();
        return kExitStartFailure;
      }
      trigger = std::make_unique<Trigger>(std::move(t));
      break;
    }
  }
  return kExitOk;
}

}  // namespace storetrack::unit
