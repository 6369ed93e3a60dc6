// storetrack-eval noise-floor: read, evaluate, write the result JSON, print seed 002's tables.
#pragma once

#include <ostream>

#include <nlohmann/json.hpp>
#include "eval_cli.hpp"

namespace storetrack::evalapp {

/// 0 ok, 1 the result file could not be written, 2 bad input (message on `err`).
int run_noise_floor(const NoiseFloorArgs& args, std::ostream& out, std::ostream& err);

/// The machine-readable result (docs/evaluation.md, "Noise floor", result JSON).
nlohmann::json noise_floor_json(const eval::NoiseFloorResult& r, const NoiseFloorArgs& args);

/// The terminal summary (units and k stated).
void print_noise_floor(const eval::NoiseFloorResult& r, std::ostream& out);

}  // namespace storetrack::evalapp
