// The unit's Modbus register map: ONE table, from which the server's address ranges, range
// checks and docs/modbus.md are all derived (render_register_map_markdown(); a test keeps the
// document equal to the table, and `storetrack-unit modbus-doc` regenerates it).
//
// 32-bit values occupy two registers, high word first (the usual "big-endian word order").
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>

namespace storetrack::health {

enum class RegisterKind : std::uint8_t { kInput, kHolding };
enum class ValueType : std::uint8_t { kU16, kI16, kU32, kI32 };

/// Input registers (function code 0x04, read-only health).
enum class InputField : std::uint8_t {
  kUptimeS,
  kFramesCaptured,
  kFramesDropped,
  kTriggersSeen,
  kTriggersMissing,
  kTriggersExtra,
  kObservationsSent,
  kLinkTxErrors,
  kLinkTxDropped,
  kCanBusOffCount,
  kCanErrorFrames,
  kCentroidTimeUsMax,
  kStatus,
  kClockState,
  kBoardTempCdeg,
  kSensorTempCdeg,
  kPtpOffsetNs,
  kMarksLastFrame,
  kFirmwareVersion,
  kConfigGeneration,
  kCentroidErrors,
  kCount
};

/// Holding registers (0x03 read, 0x06 / 0x10 write in maintenance mode only).
enum class HoldingField : std::uint8_t {
  kUnitId,
  kCameraId,
  kExposureUs,
  kTriggerRateHz,
  kPulseWidthUs,
  kThresholdDn,
  kRoiX,
  kRoiY,
  kRoiWidth,
  kRoiHeight,
  kCount
};

struct RegisterDef {
  RegisterKind kind;
  std::uint16_t address;  ///< 0-based protocol address
  ValueType type;
  std::uint8_t field;  ///< InputField or HoldingField
  const char* name;
  const char* unit;
  std::int32_t min;  ///< holding: accepted range (inclusive); input: informative
  std::int32_t max;
  std::int32_t default_value;  ///< holding: value at start when the config file has none
  const char* doc;
};

inline constexpr int words(ValueType t) {
  return t == ValueType::kU32 || t == ValueType::kI32 ? 2 : 1;
}

// clang-format off
inline constexpr RegisterDef kRegisterMap[] = {
  // kind, addr, type, field, name, unit, min, max, default, doc
  {RegisterKind::kInput, 0, ValueType::kU32, std::uint8_t(InputField::kUptimeS), "uptime_s", "s", 0, 0, 0, "Seconds since the unit process started"},
  {RegisterKind::kInput, 2, ValueType::kU32, std::uint8_t(InputField::kFramesCaptured), "frames_captured", "1", 0, 0, 0, "Frames dequeued from the camera (wraps)"},
  {RegisterKind::kInput, 4, ValueType::kU32, std::uint8_t(InputField::kFramesDropped), "frames_dropped", "1", 0, 0, 0, "Frames lost: sequence gaps and late processing"},
  {RegisterKind::kInput, 6, ValueType::kU32, std::uint8_t(InputField::kTriggersSeen), "triggers_seen", "1", 0, 0, 0, "Trigger edges generated (master) or received (slave)"},
  {RegisterKind::kInput, 8, ValueType::kU32, std::uint8_t(InputField::kTriggersMissing), "triggers_missing", "1", 0, 0, 0, "Frames that had no trigger edge"},
  {RegisterKind::kInput, 10, ValueType::kU32, std::uint8_t(InputField::kTriggersExtra), "triggers_extra", "1", 0, 0, 0, "Trigger edges that produced no frame (incl. off-phase edges)"},
  {RegisterKind::kInput, 12, ValueType::kU32, std::uint8_t(InputField::kObservationsSent), "observations_sent", "1", 0, 0, 0, "MarkObservations messages sent (all links)"},
  {RegisterKind::kInput, 14, ValueType::kU32, std::uint8_t(InputField::kLinkTxErrors), "link_tx_errors", "1", 0, 0, 0, "Send errors on any link"},
  {RegisterKind::kInput, 16, ValueType::kU32, std::uint8_t(InputField::kLinkTxDropped), "link_tx_dropped", "1", 0, 0, 0, "Exposures dropped by transmit back-pressure or bus-off"},
  {RegisterKind::kInput, 18, ValueType::kU16, std::uint8_t(InputField::kCanBusOffCount), "can_bus_off_count", "1", 0, 0, 0, "CAN bus-off events (wraps)"},
  {RegisterKind::kInput, 19, ValueType::kU16, std::uint8_t(InputField::kCanErrorFrames), "can_error_frames", "1", 0, 0, 0, "CAN error frames received (wraps)"},
  {RegisterKind::kInput, 20, ValueType::kU16, std::uint8_t(InputField::kCentroidTimeUsMax), "centroid_time_us_max", "us", 0, 0, 0, "Longest centroiding time of one frame in the last health period"},
  {RegisterKind::kInput, 21, ValueType::kU16, std::uint8_t(InputField::kStatus), "status", "bitfield", 0, 0, 0, "UnitHealth status bits: 0 capturing, 1 maintenance, 2 trigger master, 3 CAN bus-off, 4 camera error, 5 trigger error, 6 centroid error"},
  {RegisterKind::kInput, 22, ValueType::kU16, std::uint8_t(InputField::kClockState), "clock_state", "enum", 0, 0, 0, "0 free-running, 1 locking, 2 locked, 3 holdover"},
  {RegisterKind::kInput, 23, ValueType::kI16, std::uint8_t(InputField::kBoardTempCdeg), "board_temp_cdeg", "0.01 degC", 0, 0, 0, "Board (SoC) temperature from /sys/class/thermal; -32768 when absent"},
  {RegisterKind::kInput, 24, ValueType::kI16, std::uint8_t(InputField::kSensorTempCdeg), "sensor_temp_cdeg", "0.01 degC", 0, 0, 0, "Image sensor temperature; -32768 when absent"},
  {RegisterKind::kInput, 25, ValueType::kI32, std::uint8_t(InputField::kPtpOffsetNs), "ptp_offset_ns", "ns", 0, 0, 0, "Last PTP offset from master; INT32_MIN when unknown"},
  {RegisterKind::kInput, 27, ValueType::kU16, std::uint8_t(InputField::kMarksLastFrame), "marks_last_frame", "1", 0, 0, 0, "Marks detected in the last frame"},
  {RegisterKind::kInput, 28, ValueType::kU16, std::uint8_t(InputField::kFirmwareVersion), "firmware_version", "major*256+minor", 0, 0, 0, "storetrack-unit version"},
  {RegisterKind::kInput, 29, ValueType::kU16, std::uint8_t(InputField::kConfigGeneration), "config_generation", "1", 0, 0, 0, "Incremented on every accepted configuration write"},
  {RegisterKind::kInput, 30, ValueType::kU32, std::uint8_t(InputField::kCentroidErrors), "centroid_errors", "1", 0, 0, 0, "Frames the centroider refused (no observation sent; consecutive ones end the run at run.max_consecutive_errors)"},
  {RegisterKind::kHolding, 0, ValueType::kU16, std::uint8_t(HoldingField::kUnitId), "unit_id", "1", 0, 254, 0, "Camera unit id in messages"},
  {RegisterKind::kHolding, 1, ValueType::kU16, std::uint8_t(HoldingField::kCameraId), "camera_id", "1", 0, 254, 0, "Camera id in messages"},
  {RegisterKind::kHolding, 2, ValueType::kU16, std::uint8_t(HoldingField::kExposureUs), "exposure_us", "us", 10, 20000, 1000, "Exposure time (V4L2 exposure control when configured; reported in messages)"},
  {RegisterKind::kHolding, 3, ValueType::kU16, std::uint8_t(HoldingField::kTriggerRateHz), "trigger_rate_hz", "Hz", 1, 400, 100, "Trigger rate (master mode generator; slave mode pairing period)"},
  {RegisterKind::kHolding, 4, ValueType::kU16, std::uint8_t(HoldingField::kPulseWidthUs), "pulse_width_us", "us", 1, 5000, 100, "Master-mode trigger pulse width; must be < 90 % of the period"},
  {RegisterKind::kHolding, 5, ValueType::kU16, std::uint8_t(HoldingField::kThresholdDn), "threshold_dn", "DN", 0, 65535, 0, "Centroider detection threshold above background; 0 = automatic (threshold_sigma x background noise)"},
  {RegisterKind::kHolding, 6, ValueType::kU16, std::uint8_t(HoldingField::kRoiX), "roi_x", "px", 0, 4095, 0, "Search region left column"},
  {RegisterKind::kHolding, 7, ValueType::kU16, std::uint8_t(HoldingField::kRoiY), "roi_y", "px", 0, 4095, 0, "Search region top row"},
  {RegisterKind::kHolding, 8, ValueType::kU16, std::uint8_t(HoldingField::kRoiWidth), "roi_width", "px", 0, 4096, 0, "Search region width; 0 = to the right edge"},
  {RegisterKind::kHolding, 9, ValueType::kU16, std::uint8_t(HoldingField::kRoiHeight), "roi_height", "px", 0, 4096, 0, "Search region height; 0 = to the bottom edge"},
};
// clang-format on

/// Number of registers of a kind (highest address + width).
int register_count(RegisterKind kind);
/// The definition covering `address` (either word of a 32-bit value), or nullptr.
const RegisterDef* find_register(RegisterKind kind, std::uint16_t address);
const RegisterDef& holding_def(HoldingField f);
const RegisterDef& input_def(InputField f);

/// Checks that the table is consistent (no overlaps, every field exactly once, defaults in
/// range). Returns an empty string or the first problem.
std::string check_register_map();

/// Validates a write of `values` starting at holding `address` against the table and the
/// cross-register rules, given the current holding values. Returns 0 (all accepted),
/// -EFAULT (address outside the map: ILLEGAL DATA ADDRESS) or -EINVAL (value out of range:
/// ILLEGAL DATA VALUE); *why says which register.
/// What the table alone cannot know: the frame the search region must fit (0: not checked).
struct HoldingLimits {
  int frame_width = 0;
  int frame_height = 0;
};

int validate_holding_write(std::span<const std::uint16_t> current, std::uint16_t address,
                           std::span<const std::uint16_t> values, std::string* why = nullptr,
                           const HoldingLimits& limits = {});

/// docs/modbus.md, generated from the table.
std::string render_register_map_markdown();

}  // namespace storetrack::health
