#include "storetrack/health/unit_state.hpp"

#include <cerrno>
#include <filesystem>
#include <fstream>

namespace storetrack::health {

ConfigStore::ConfigStore() {
  for (const RegisterDef& d : kRegisterMap) {
    if (d.kind == RegisterKind::kHolding) {
      values_[d.field].store(static_cast<std::uint16_t>(d.default_value));
    }
  }
}

void ConfigStore::read_all(std::span<std::uint16_t> out) const {
  for (const RegisterDef& d : kRegisterMap) {
    if (d.kind == RegisterKind::kHolding && d.address < out.size()) {
      out[d.address] = values_[d.field].load(std::memory_order_relaxed);
    }
  }
}

ConfigStore::Values ConfigStore::snapshot() const {
  Values out{};
  for (;;) {
    const std::uint32_t before = sequence_.load(std::memory_order_acquire);
    if (before & 1u) continue;  // a write is being stored
    for (std::size_t i = 0; i < kHoldingCount; ++i)
      out[i] = values_[i].load(std::memory_order_relaxed);
    std::atomic_thread_fence(std::memory_order_acquire);
    if (sequence_.load(std::memory_order_relaxed) == before) return out;
  }
}

int ConfigStore::write(std::uint16_t address, std::span<const std::uint16_t> values,
                       std::string* why) {
  std::array<std::uint16_t, kHoldingCount> current{};
  read_all(current);
  if (int rc = validate_holding_write(current, address, values, why, limits_); rc < 0) return rc;
  if (identity_locked_.load(std::memory_order_relaxed)) {
    for (std::size_t i = 0; i < values.size(); ++i) {
      const RegisterDef* d =
          find_register(RegisterKind::kHolding, static_cast<std::uint16_t>(address + i));
      const auto f = static_cast<HoldingField>(d->field);
      if ((f == HoldingField::kUnitId || f == HoldingField::kCameraId) &&
          values[i] != current[d->address]) {
        if (why != nullptr) *why = std::string(d->name) + " changes only at a restart";
        return -EBUSY;
      }
    }
  }
  sequence_.fetch_add(1, std::memory_order_relaxed);  // odd: readers retry
  std::atomic_thread_fence(std::memory_order_release);
  for (std::size_t i = 0; i < values.size(); ++i) {
    const RegisterDef* d =
        find_register(RegisterKind::kHolding, static_cast<std::uint16_t>(address + i));
    values_[d->field].store(values[i], std::memory_order_relaxed);
  }
  sequence_.fetch_add(1, std::memory_order_release);  // even: whole again
  generation_.fetch_add(1, std::memory_order_release);
  return 0;
}

namespace {

void put(std::span<std::uint16_t> regs, InputField f, std::int64_t value) {
  const RegisterDef& d = input_def(f);
  if (d.address + words(d.type) > static_cast<int>(regs.size())) return;
  const auto u = static_cast<std::uint32_t>(value);  // two's complement for signed types
  if (words(d.type) == 2) {
    regs[d.address] = static_cast<std::uint16_t>(u >> 16);
    regs[d.address + 1u] = static_cast<std::uint16_t>(u & 0xFFFF);
  } else {
    regs[d.address] = static_cast<std::uint16_t>(u & 0xFFFF);
  }
}

std::int64_t ld(const std::atomic<std::uint64_t>& a) {
  return static_cast<std::int64_t>(a.load(std::memory_order_relaxed) & 0xFFFFFFFFu);
}

}  // namespace

void fill_input_registers(const UnitCounters& c, std::uint32_t uptime_s,
                          std::uint32_t config_generation, std::span<std::uint16_t> regs) {
  put(regs, InputField::kUptimeS, uptime_s);
  put(regs, InputField::kFramesCaptured, ld(c.frames_captured));
  put(regs, InputField::kFramesDropped, ld(c.frames_dropped));
  put(regs, InputField::kTriggersSeen, ld(c.triggers_seen));
  put(regs, InputField::kTriggersMissing, ld(c.triggers_missing));
  put(regs, InputField::kTriggersExtra, ld(c.triggers_extra));
  put(regs, InputField::kObservationsSent, ld(c.observations_sent));
  put(regs, InputField::kLinkTxErrors, ld(c.link_tx_errors));
  put(regs, InputField::kLinkTxDropped, ld(c.link_tx_dropped));
  put(regs, InputField::kCanBusOffCount, ld(c.can_bus_off_count));
  put(regs, InputField::kCanErrorFrames, ld(c.can_error_frames));
  put(regs, InputField::kCentroidTimeUsMax, c.centroid_time_us_max.load(std::memory_order_relaxed));
  put(regs, InputField::kStatus, c.status.load(std::memory_order_relaxed));
  put(regs, InputField::kClockState, c.clock_state.load(std::memory_order_relaxed));
  put(regs, InputField::kBoardTempCdeg, c.board_temp_cdeg.load(std::memory_order_relaxed));
  put(regs, InputField::kSensorTempCdeg, c.sensor_temp_cdeg.load(std::memory_order_relaxed));
  put(regs, InputField::kPtpOffsetNs, c.ptp_offset_ns.load(std::memory_order_relaxed));
  put(regs, InputField::kMarksLastFrame, c.marks_last_frame.load(std::memory_order_relaxed));
  put(regs, InputField::kFirmwareVersion, kFirmwareVersion);
  put(regs, InputField::kConfigGeneration, config_generation & 0xFFFF);
  put(regs, InputField::kCentroidErrors, ld(c.centroid_errors));
}

std::int16_t read_board_temp_cdeg(const std::string& root) {
  namespace fs = std::filesystem;
  std::error_code ec;
  long best_mdeg = LONG_MIN;
  for (const auto& entry : fs::directory_iterator(root, ec)) {
    if (entry.path().filename().string().rfind("thermal_zone", 0) != 0) continue;
    std::ifstream in(entry.path() / "temp");
    long mdeg = 0;
    if (in >> mdeg && mdeg > best_mdeg) best_mdeg = mdeg;  // millidegrees Celsius
  }
  if (best_mdeg == LONG_MIN) return INT16_MIN;
  const long cdeg = best_mdeg / 10;
  if (cdeg > INT16_MAX) return INT16_MAX;
  if (cdeg <= INT16_MIN) return INT16_MIN + 1;
  return static_cast<std::int16_t>(cdeg);
}

}  // namespace storetrack::health
