#include "input/trigger.hpp"

namespace storetrack::unit {

Trigger::Trigger(std::unique_ptr<trigger::TriggerLine> line) : line_(std::move(line)) {}

Trigger::~Trigger() = default;

}  // namespace storetrack::unit
