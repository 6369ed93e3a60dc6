#include "storetrack/health/register_map.hpp"

#include <cerrno>
#include <sstream>
#include <vector>

namespace storetrack::health {
namespace {

const char* type_name(ValueType t) {
  switch (t) {
    case ValueType::kU16:
      return "u16";
    case ValueType::kI16:
      return "i16";
    case ValueType::kU32:
      return "u32";
    case ValueType::kI32:
      return "i32";
  }
  return "?";
}

}  // namespace

int register_count(RegisterKind kind) {
  int n = 0;
  for (const RegisterDef& d : kRegisterMap) {
    if (d.kind == kind && d.address + words(d.type) > n) n = d.address + words(d.type);
  }
  return n;
}

const RegisterDef* find_register(RegisterKind kind, std::uint16_t address) {
  for (const RegisterDef& d : kRegisterMap) {
    if (d.kind == kind && address >= d.address && address < d.address + words(d.type)) return &d;
  }
  return nullptr;
}

const RegisterDef& holding_def(HoldingField f) {
  for (const RegisterDef& d : kRegisterMap) {
    if (d.kind == RegisterKind::kHolding && d.field == static_cast<std::uint8_t>(f)) return d;
  }
  return kRegisterMap[0];  // unreachable when check_register_map() passes (tested)
}

const RegisterDef& input_def(InputField f) {
  for (const RegisterDef& d : kRegisterMap) {
    if (d.kind == RegisterKind::kInput && d.field == static_cast<std::uint8_t>(f)) return d;
  }
  return kRegisterMap[0];
}

std::string check_register_map() {
  for (RegisterKind kind : {RegisterKind::kInput, RegisterKind::kHolding}) {
    const int n = register_count(kind);
    std::vector<int> owner(static_cast<std::size_t>(n), 0);
    std::vector<int> field_seen(64, 0);
    for (const RegisterDef& d : kRegisterMap) {
      if (d.kind != kind) continue;
      for (int w = 0; w < words(d.type); ++w)
        ++owner[static_cast<std::size_t>(d.address + w)];
      ++field_seen[d.field];
      if (kind == RegisterKind::kHolding) {
        if (d.type != ValueType::kU16) return std::string(d.name) + ": holding registers are u16";
        if (d.min > d.max || d.default_value < d.min || d.default_value > d.max) {
          return std::string(d.name) + ": default outside [min, max]";
        }
        if (d.min < 0 || d.max > 65535) return std::string(d.name) + ": range exceeds u16";
      }
    }
    for (int a = 0; a < n; ++a) {
      if (owner[static_cast<std::size_t>(a)] != 1) {
        return "address " + std::to_string(a) +
               (owner[static_cast<std::size_t>(a)] ? " overlaps" : " is a gap");
      }
    }
    const int fields = kind == RegisterKind::kInput ? static_cast<int>(InputField::kCount)
                                                    : static_cast<int>(HoldingField::kCount);
    for (int f = 0; f < fields; ++f) {
      if (field_seen[static_cast<std::size_t>(f)] != 1) {
        return "field " + std::to_string(f) + " appears " +
               std::to_string(field_seen[static_cast<std::size_t>(f)]) + " times";
      }
    }
  }
  return {};
}

namespace {

// The search region inside the frame (a region outside it gave 0 marks, silently).
bool roi_fits(std::span<const std::uint16_t> after, const HoldingLimits& limits) {
  const auto fits = [](int origin, int size, int frame) {
    return frame <= 0 || (origin < frame && origin + size <= frame);
  };
  const auto v = [&](HoldingField f) { return int{after[holding_def(f).address]}; };
  return fits(v(HoldingField::kRoiX), v(HoldingField::kRoiWidth), limits.frame_width) &&
         fits(v(HoldingField::kRoiY), v(HoldingField::kRoiHeight), limits.frame_height);
}

}  // namespace

int validate_holding_write(std::span<const std::uint16_t> current, std::uint16_t address,
                           std::span<const std::uint16_t> values, std::string* why,
                           const HoldingLimits& limits) {
  const int n = register_count(RegisterKind::kHolding);
  if (values.empty() || address + values.size() > static_cast<std::size_t>(n) ||
      current.size() < static_cast<std::size_t>(n)) {
    if (why != nullptr) *why = "address range outside the holding map";
    return -EFAULT;
  }
  std::vector<std::uint16_t> after(current.begin(), current.begin() + n);
  for (std::size_t i = 0; i < values.size(); ++i) {
    const auto a = static_cast<std::uint16_t>(address + i);
    const RegisterDef* d = find_register(RegisterKind::kHolding, a);
    if (d == nullptr) {
      if (why != nullptr) *why = "no holding register at " + std::to_string(a);
      return -EFAULT;
    }
    if (values[i] < d->min || values[i] > d->max) {
      if (why != nullptr) {
        *why = std::string(d->name) + " = " + std::to_string(values[i]) + " outside [" +
               std::to_string(d->min) + ", " + std::to_string(d->max) + "]";
      }
      return -EINVAL;
    }
    after[a] = values[i];
  }
  // Cross-register rule: the pulse must end well before the next one starts.
  const auto rate = after[holding_def(HoldingField::kTriggerRateHz).address];
  const auto width = after[holding_def(HoldingField::kPulseWidthUs).address];
  if (static_cast<double>(width) * rate >= 0.9e6) {
    if (why != nullptr) *why = "pulse_width_us * trigger_rate_hz must be < 900000 (90 % duty)";
    return -EINVAL;
  }
  const auto exposure = after[holding_def(HoldingField::kExposureUs).address];
  if (static_cast<double>(exposure) * rate >= 1e6) {
    if (why != nullptr) *why = "exposure_us must be shorter than the trigger period";
    return -EINVAL;
  }
  if (!roi_fits(after, limits)) {
    if (why != nullptr)
      *why = "the search region must lie inside the " + std::to_string(limits.frame_width) + " x " +
             std::to_string(limits.frame_height) + " frame";
    return -EINVAL;
  }
  return 0;
}

std::string render_register_map_markdown() {
  std::ostringstream md;
  md << "# Modbus TCP register map of storetrack-unit\n\n"
     << "<!-- Generated from firmware/health/include/storetrack/health/register_map.hpp by\n"
     << "     `storetrack-unit modbus-doc > docs/modbus.md`; test_firmware_health checks it. "
        "-->\n\n"
     << "The unit serves Modbus TCP (libmodbus 3.1.6) on the configured address, by default\n"
     << "`127.0.0.1:1502` (never all interfaces unless configured so). Addresses are 0-based\n"
     << "protocol addresses. 32-bit values take two registers, high word first.\n\n"
     << "## Function codes\n\n"
     << "| code | function | accepted |\n|---|---|---|\n"
     << "| 0x03 | read holding registers | always |\n"
     << "| 0x04 | read input registers | always |\n"
     << "| 0x06 | write single register | maintenance mode only |\n"
     << "| 0x10 | write multiple registers | maintenance mode only (all-or-nothing) |\n"
     << "| any other (0x01, 0x02, 0x05, 0x0F, 0x11, 0x16, 0x17, ...) | | refused: exception 0x01 "
        "ILLEGAL FUNCTION |\n\n"
     << "## Exceptions\n\n"
     << "| exception | when |\n|---|---|\n"
     << "| 0x01 ILLEGAL FUNCTION | function code not in the table above |\n"
     << "| 0x02 ILLEGAL DATA ADDRESS | a register outside the map below |\n"
     << "| 0x03 ILLEGAL DATA VALUE | a value outside its range, a broken cross-register rule, or a "
        "malformed request (a quantity out of range, a length that is not the function's) |\n"
     << "| 0x04 SERVER DEVICE FAILURE | a write while the unit is NOT in maintenance mode "
        "(`--maintenance` / `\"modbus\": {\"maintenance\": true}`) |\n"
     << "| 0x06 SERVER DEVICE BUSY | a write that changes `unit_id` or `camera_id` while the unit "
        "runs: the identity changes only when the unit restarts with it in its configuration |"
        "\n\n"
     << "Maintenance mode is set only from the unit's command line or configuration file, never\n"
     << "over Modbus. Cross-register rules: `pulse_width_us * trigger_rate_hz < 900000`,\n"
     << "`exposure_us * trigger_rate_hz < 1000000`; the search region (`roi_*`) inside the\n"
     << "frame. A write is checked whole and applied whole: the capture loop never sees half of a\n"
     << "multi-register write. A trigger change the generator cannot start leaves the previous\n"
     << "trigger running (stats `config_apply_errors`). Malformed or truncated requests close\n"
     << "that client's connection; the server keeps serving the others. Requests are read\n"
     << "without blocking: a slow client holds nobody else; a request not complete within 1 s,\n"
     << "or a connection quiet for 60 s, is closed; when all 4 connections are taken, the\n"
     << "quietest one makes room for a new client.\n\n";
  for (RegisterKind kind : {RegisterKind::kInput, RegisterKind::kHolding}) {
    const bool input = kind == RegisterKind::kInput;
    md << (input ? "## Input registers (0x04, health)\n\n"
                 : "## Holding registers (0x03 / 0x06 / 0x10, configuration)\n\n");
    md << (input ? "| address | words | type | name | unit | description "
                   "|\n|---|---|---|---|---|---|\n"
                 : "| address | type | name | unit | min | max | default | description "
                   "|\n|---|---|---|---|---|---|---|---|\n");
    for (const RegisterDef& d : kRegisterMap) {
      if (d.kind != kind) continue;
      if (input) {
        md << "| " << d.address << " | " << words(d.type) << " | " << type_name(d.type) << " | `"
           << d.name << "` | " << d.unit << " | " << d.doc << " |\n";
      } else {
        md << "| " << d.address << " | " << type_name(d.type) << " | `" << d.name << "` | "
           << d.unit << " | " << d.min << " | " << d.max << " | " << d.default_value << " | "
           << d.doc << " |\n";
      }
    }
    md << "\n";
  }
  return md.str();
}

}  // namespace storetrack::health
