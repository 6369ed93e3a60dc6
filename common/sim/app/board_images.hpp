// storetrack-sim --mode boards: the calibration board set of a scenario's rig as PNG images
// plus its truth (common/sim/README.md, "Board images").
#pragma once

#include <cstdint>
#include <string>

#include "storetrack/sim/board_set.hpp"
#include "storetrack/sim/simulator.hpp"

namespace storetrack::sim_app {

/// Writes <out_dir>/boards/cam<id>/frame_NNNN.png for every frame and camera and
/// <out_dir>/boards/truth.json; prints one line per camera. Throws on I/O errors.
void write_board_images(const sim::Simulator& simulator, const sim::BoardSetOptions& options,
                        std::uint64_t seed, const std::string& out_dir);

}  // namespace storetrack::sim_app
