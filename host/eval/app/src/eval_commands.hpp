// The subcommands of storetrack-eval: read, evaluate, write the result JSON, print the summary.
#pragma once

#include <ostream>

#include <nlohmann/json.hpp>
#include "eval_cli.hpp"

namespace storetrack::evalapp {

/// 0 ok, 1 the result file could not be written, 2 bad input (message on `err`).
int run_type_a(const TypeAArgs& args, std::ostream& out, std::ostream& err);

/// The machine-readable result (docs/evaluation.md, "Result JSON").
nlohmann::json type_a_json(const eval::TypeAResult& r, const TypeAArgs& args);

}  // namespace storetrack::evalapp
