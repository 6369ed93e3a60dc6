// The unit's simulated mode from the scene simulator (common/sim): one camera of a scenario,
// rendered frame by frame (sim::SimFrameSource), with the simulator's clock and trigger model.
#include <string>

#include "simulated_camera.hpp"
#include "storetrack/sim/frame_source.hpp"
#include "storetrack/sim/scenario.hpp"
#include "storetrack/sim/simulator.hpp"

namespace storetrack::unit {
namespace {

constexpr int kRealtimeBackgroundPool = 8;

bool make_simulated_camera(const SimSourceConfig& config, SimulatedCamera& out,
                           std::string& error) {
  const sim::Scenario scenario = sim::load_scenario(config.scenario);
  auto simulator = std::make_shared<const sim::Simulator>(scenario, config.seed);
  if (config.camera_index < 0 || config.camera_index >= simulator->num_cameras()) {
    error = "sim camera index " + std::to_string(config.camera_index) + " outside 0.." +
            std::to_string(simulator->num_cameras() - 1);
    return false;
  }
  if (config.start_exposure >= simulator->num_exposures()) {
    error = "sim start exposure " + std::to_string(config.start_exposure) + " outside 0.." +
            std::to_string(simulator->num_exposures() - 1);
    return false;
  }
  const auto index = static_cast<std::size_t>(config.camera_index);
  out.unit_id = scenario.cameras[index].unit_id;
  out.camera_id = scenario.cameras[index].camera_id;
  const auto& intrinsics = simulator->true_rig().cameras[index].model.intrinsics();
  out.width = intrinsics.width;
  out.height = intrinsics.height;
  out.clock_state = static_cast<std::uint8_t>(scenario.clock_state);
  out.clock_sigma_ns = scenario.ptp_offset_sigma_ns;
  // The simulated unit's clocks: TAI = monotonic + a fixed offset (Simulator timing model).
  const sim::ExposureTiming t0 = simulator->exposure_timing(0, config.camera_index);
  out.tai_minus_mono_ns = t0.reported_start_tai_ns - t0.reported_start_mono_ns;
  out.frame_rate_hz = scenario.frame_rate_hz;
  out.first_trigger_seq = t0.trigger_seq;
  // Paced at the frame rate, a whole frame per exposure is too slow to render (docs:
  // SimFrameSource); the pool of backgrounds keeps the spots exact and the unit on time.
  // Slow motion (--sim-pace-hz) has time for whole frames: they stay exact.
  const bool full_rate = config.realtime && config.pace_hz <= 0;
  const int pool = config.background_pool >= 0 ? config.background_pool
                   : full_rate                 ? kRealtimeBackgroundPool
                                               : 0;
  auto source =
      std::make_unique<sim::SimFrameSource>(*simulator, config.camera_index, 4, config.realtime,
                                            config.start_exposure, config.pace_hz, pool);
  if (config.realtime) {
    if (config.pace_origin_mono_ns > 0) source->set_pace_origin(config.pace_origin_mono_ns);
    const sim::SimFrameSource* paced = source.get();
    out.pacing = [paced] {
      const sim::SimFrameSource::Pacing p = paced->pacing();
      return SimulatedPacing{p.max_behind_ns, p.frames_late, p.frame_period_ns};
    };
  }
  out.source = std::move(source);
  out.simulation = std::move(simulator);
  return true;
}

}  // namespace

SimulatedCameraFactory simulator_camera_factory() {
  return make_simulated_camera;
}

}  // namespace storetrack::unit
