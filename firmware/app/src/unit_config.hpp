// storetrack-unit configuration: a JSON file (docs/unit-config.md) with command-line overrides.
// Parsing throws ConfigError with the offending key; nothing here runs per frame.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "storetrack/capture/fault_injecting_frame_source.hpp"
#include "storetrack/capture/v4l2_frame_source.hpp"
#include "storetrack/centroid/centroider.hpp"
#include "storetrack/clock/clock_monitor.hpp"
#include "storetrack/link/canfd_link.hpp"
#include "storetrack/link/udp_link.hpp"

namespace storetrack::unit {

class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

enum class SourceType { kSim, kReplay, kV4l2, kNone };
enum class TriggerMode { kNone, kSim, kGpioMaster, kGpioSlave };

struct SimSourceConfig {
  std::string scenario;
  int camera_index = 0;
  std::uint64_t seed = 1;
  bool realtime = false;
  /// Fault injection (tests): start at this exposure as a unit (re)started mid-run does; its
  /// trigger numbering then starts from 0, not from the simulator's sequence.
  int start_exposure = 0;
  /// With start_exposure: the restarted unit keeps the rig's trigger numbering (a unit that
  /// persisted its edge count, or a slave of a master that kept counting) instead of 0.
  bool keep_numbering = false;
  /// With realtime: CLOCK_MONOTONIC time [ns] exposure 0 is due at, shared by the units of one
  /// run so they keep one schedule (a restarted unit too); 0: each unit's own start.
  std::int64_t pace_origin_mono_ns = 0;
  /// With realtime: pace at this rate [Hz] instead of the scenario's (slow motion); 0: scenario.
  double pace_hz = 0;
  /// Backgrounds rendered at start, the spots drawn over them per exposure
  /// (sim::SimFrameSource); 0: every frame rendered whole; -1: 8 with realtime at the
  /// scenario's rate (no pace_hz), else 0.
  int background_pool = -1;
  /// Fault injection (tests): the unit's TAI clock steps by tai_step_ns for the exposures
  /// [tai_step_from, tai_step_to) and back after (a PTP step), its monotonic clock does not.
  int tai_step_from = -1;
  int tai_step_to = -1;
  std::int64_t tai_step_ns = 0;
};

struct ReplaySourceConfig {
  std::string directory;
  double rate_hz = 0;
  bool loop = false;
};

struct V4l2SourceConfig {
  capture::V4L2Config device;
  std::string exposure_control;  ///< control name for exposure_us ("" = not set by the unit)
  double exposure_control_unit_us = 100;  ///< V4L2 exposure_time_absolute counts 100 us
};

struct TriggerConfig {
  TriggerMode mode = TriggerMode::kNone;
  double rate_hz = 100;
  std::int64_t pulse_width_ns = 100'000;
  std::string chip = "/dev/gpiochip0";
  std::vector<unsigned> lines{0};  ///< master outputs
  unsigned line = 0;               ///< slave input
  bool active_low = false;
  std::int64_t latency_ns = 0;                ///< frame time stamp - edge
  std::int64_t match_tolerance_ns = -1;       ///< -1: period / 4
  std::int64_t edge_phase_tolerance_ns = -1;  ///< -1: period / 4
  std::int64_t trigger_to_exposure_ns = 0;
  // sim trigger faults (tests and demos)
  std::int64_t sim_jitter_ns = 0;
  int sim_drop_every = 0;
  int sim_extra_every = 0;
  int sim_read_error_every = 0;
  std::string edges_csv;  ///< write every edge (trigger-only runs, bench)
  /// Only frames a trigger edge claims are sent; frames with no marks never claim one. For a
  /// FREE-RUNNING source standing in for a camera in external-trigger mode (vivid on the VM rig,
  /// whose capture delivers dark frames between the triggered ones). Skipped frames are counted.
  bool triggered_only = false;
};

/// What the unit adds to its clock's uncertainty in each observation's exposure_time_sigma_ns
/// (docs/unit-config.md, "time"). Jitter belongs here only where the calibration's
/// exposure_offset_sigma_ns leaves it out (the simulator's calibrations include it).
struct TimeUncertaintyConfig {
  /// A configured (not ptp4l) clock's uncertainty; -1: auto (the sim scenario's
  /// ptp_offset_sigma_ns, else 0).
  double clock_sigma_ns = -1;
  double latch_jitter_ns = 0;         ///< trigger edge time stamp jitter, 1 sigma
  double sensor_start_jitter_ns = 0;  ///< the sensor's trigger-to-exposure-start jitter, 1 sigma
};

struct UnitConfig {
  int unit_id = 0;
  int camera_id = 0;
  SourceType source = SourceType::kSim;
  SimSourceConfig sim;
  ReplaySourceConfig replay;
  V4l2SourceConfig v4l2;
  TriggerConfig trigger;
  centroid::CentroidConfig centroid;
  int roi_x = 0, roi_y = 0, roi_width = 0, roi_height = 0;
  std::vector<link::UdpLinkConfig> udp;
  std::vector<link::CanFdLinkConfig> canfd;
  int health_period_ms = 1000;
  /// Where the board temperature is read (thermal_zone*/temp); another root for tests.
  std::string board_temp_root = "/sys/class/thermal";
  bool modbus_enabled = true;
  std::string modbus_address = "127.0.0.1";
  int modbus_port = 1502;
  bool maintenance = false;
  /// auto | free-running | locking | locked | holdover: reported as configured (auto: the
  /// simulator scenario's, else free-running); ptp4l: measured from ptp4l (the "ptp4l" section)
  std::string clock_state = "auto";
  /// clock_state ptp4l: where ptp4l listens and the lock thresholds (docs/deploy.md, "Clock");
  /// its poll period is health_period_ms.
  clock::ClockMonitorConfig ptp4l;
  TimeUncertaintyConfig time;
  std::uint32_t exposure_us = 1000;
  // camera recovery: a device that is gone is reopened after reopen_first_ms, then at doubling
  // intervals up to reopen_max_ms, while the trigger keeps running (docs/reliability.md)
  int camera_reopen_first_ms = 50;
  int camera_reopen_max_ms = 2000;
  capture::CameraFaultPlan camera_faults;  ///< injected camera faults (tests, demos)
  // run control
  long frames = 0;         ///< stop after this many frames (0: until the source ends / signal)
  double duration_s = 0;   ///< stop after this long (0: no limit)
  std::string stats_json;  ///< write counters here at exit
  int max_consecutive_errors = 50;
  bool verbose = false;
};

SourceType parse_source(const std::string& s);
TriggerMode parse_trigger_mode(const std::string& s);
const char* to_string(SourceType s);
const char* to_string(TriggerMode m);

/// Reads a JSON configuration file into `config` (keys absent keep their defaults; unknown
/// keys are an error, so typos do not pass silently).
void load_config_file(const std::string& path, UnitConfig& config);
void parse_config_json(const std::string& text, const std::string& origin, UnitConfig& config);
/// Checks ranges and combinations; throws ConfigError.
void validate(const UnitConfig& config);
/// The effective configuration as JSON (print-config).
std::string to_json(const UnitConfig& config);

}  // namespace storetrack::unit
