// The scenes of the calibration health tests: the static scenario with camera kMovedCamera
// moving in its mount (docs/calibration-health.md).
#pragma once

#include <cmath>
#include <cstdlib>
#include <optional>

#include "sim_exposure.hpp"
#include "storetrack/sim/scenario.hpp"

namespace storetrack::pipeline {

inline bool long_form() {
  const char* v = std::getenv("STORETRACK_HEALTH_LONG");
  return v != nullptr && v[0] == '1';
}

constexpr double kDeg = M_PI / 180;
constexpr int kMovedCamera = 1;

inline sim::Scenario static_scenario(int exposures,
                                     const std::optional<sim::CameraMotion>& motion) {
  sim::Scenario sc = sim::load_scenario(test::scenario_path("static"));
  sc.num_exposures = exposures;
  if (motion) sc.cameras[kMovedCamera].motion = *motion;
  return sc;
}

}  // namespace storetrack::pipeline
