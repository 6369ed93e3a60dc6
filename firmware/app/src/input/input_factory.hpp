// The one factory of the unit's inputs: the camera of `source` and the trigger of
// `trigger.mode`. Only here are the concrete kinds named (capture::V4L2FrameSource,
// capture::ReplayFrameSource, the simulated camera, trigger::GpioMasterTrigger, ...).
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "input/camera.hpp"
#include "input/trigger.hpp"
#include "simulated_camera.hpp"
#include "unit_config.hpp"

namespace storetrack::unit {

/// What a camera brings that the configuration otherwise states.
struct CameraFacts {
  int width = 0;  ///< before start(): the configured size, or the simulated camera's
  int height = 0;
  std::optional<std::uint8_t> clock_state;  ///< the scenario's (sim, clock_state "auto")
  std::optional<double> clock_sigma_ns;     ///< the scenario's (sim, time.clock_sigma_ns auto)
};

class InputFactory {
 public:
  /// `simulated` builds the camera of source "sim"; empty: the program has no simulated mode.
  InputFactory(UnitConfig& config, const SimulatedCameraFactory& simulated)
      : config_(config), simulated_(simulated) {}

  /// The camera of config.source, not started (null for "none"), behind a fault injector when
  /// faults are planned. A simulated camera fills the ids and the sim trigger's rate the
  /// configuration left open. Returns kExitOk, or kExitUsage with `error`.
  int make_camera(std::unique_ptr<Camera>& camera, CameraFacts& facts, std::string& error);
  /// The trigger of config.trigger.mode, started (null for "none"). Returns kExitOk, or
  /// kExitStartFailure with `error`.
  int make_trigger(std::int64_t period_ns, std::unique_ptr<Trigger>& trigger, std::string& error);

 private:
  UnitConfig& config_;
  const SimulatedCameraFactory& simulated_;
};

}  // namespace storetrack::unit
