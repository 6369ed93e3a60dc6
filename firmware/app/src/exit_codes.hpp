// storetrack-unit's process exit codes (docs/unit-config.md).
#pragma once

namespace storetrack::unit {

inline constexpr int kExitOk = 0;
inline constexpr int kExitRuntimeError = 1;  ///< source/trigger failed while running
inline constexpr int kExitUsage = 2;         ///< bad command line or configuration
inline constexpr int kExitStartFailure = 3;  ///< a device, link or the Modbus server did not start

}  // namespace storetrack::unit
