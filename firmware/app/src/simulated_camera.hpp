// The unit's simulated mode behind a small interface. The capture loop (storetrack_unit_core,
// a production library) knows only this header; the simulator-backed implementation
// (simulated_camera_sim.cpp, library storetrack_unit_sim) links common/sim, and only the
// programs that offer the simulated mode link it (docs/architecture.md, "No production
// library links the simulator").
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "storetrack/frame/frame_source.hpp"
#include "unit_config.hpp"

namespace storetrack::unit {

/// How far a paced simulated source fell behind its schedule (frames handed out more than one
/// frame period after their due time are late).
struct SimulatedPacing {
  std::int64_t max_behind_ns = 0;
  std::int64_t frames_late = 0;
  double frame_period_ns = 0;
};

/// A simulated camera: its frame source and the facts the unit would otherwise configure.
struct SimulatedCamera {
  std::shared_ptr<const void> simulation;      ///< what `source` renders from; outlives it
  std::unique_ptr<frame::FrameSource> source;  ///< declared after: destroyed first
  int unit_id = 0;
  int camera_id = 0;
  int width = 0;
  int height = 0;
  std::uint8_t clock_state = 0;  ///< the scenario's (clock_state "auto")
  double clock_sigma_ns = 0;     ///< the scenario's ptp_offset_sigma_ns (time.clock_sigma_ns auto)
  std::int64_t tai_minus_mono_ns = 0;  ///< the simulated unit's fixed clock offset
  double frame_rate_hz = 0;            ///< the scenario's (trigger mode sim)
  std::uint32_t first_trigger_seq = 0;
  std::function<SimulatedPacing()> pacing;  ///< set when the source is paced (realtime)
};

/// Builds the simulated camera `sim` describes. Returns false with `error` set on a bad
/// configuration (camera index, start exposure); may throw on an unreadable scenario.
using SimulatedCameraFactory =
    std::function<bool(const SimSourceConfig& sim, SimulatedCamera& out, std::string& error)>;

/// The simulator-backed factory (storetrack_unit_sim).
SimulatedCameraFactory simulator_camera_factory();

}  // namespace storetrack::unit
