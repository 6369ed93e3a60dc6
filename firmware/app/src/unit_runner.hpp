// UnitRunner: the camera unit's capture loop, wiring its parts (docs/architecture.md, "The
// unit runner"):
//   Camera -> TriggerPairing (with the Trigger's edges) -> MarkFinder -> fill_mark_message
//   -> LinkSet
// plus the periodic UnitHealth report, the Modbus registers (UnitRegisters) and the clock
// (UnitClock). setup() allocates everything; the per-frame path (run()) allocates nothing and
// throws nothing.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <span>
#include <string>

#include "clock/unit_clock.hpp"
#include "exit_codes.hpp"
#include "health/health_report.hpp"
#include "links/link_set.hpp"
#include "marks/mark_finder.hpp"
#include "message/mark_message.hpp"
#include "modbus/unit_registers.hpp"
#include "pairing/trigger_pairing.hpp"
#include "recovery/camera_recovery.hpp"
#include "simulated_camera.hpp"
#include "stats/run_counters.hpp"
#include "storetrack/centroid/centroider.hpp"
#include "storetrack/frame/frame_source.hpp"
#include "storetrack/health/board_temperature.hpp"
#include "storetrack/health/unit_state.hpp"
#include "storetrack/msg/messages.hpp"
#include "unit_config.hpp"

namespace storetrack::unit {

class Camera;   // input/camera.hpp
class Trigger;  // input/trigger.hpp
class InputFactory;

class UnitRunner {
 public:
  /// `simulated` builds the camera of source "sim"; empty: the program has no simulated mode.
  explicit UnitRunner(UnitConfig config, SimulatedCameraFactory simulated = {});
  ~UnitRunner();
  UnitRunner(const UnitRunner&) = delete;
  UnitRunner& operator=(const UnitRunner&) = delete;

  /// Builds and starts the source, trigger, links, centroider and Modbus server.
  /// Returns kExitOk, or kExitStartFailure / kExitUsage with the reason in `error`.
  int setup(std::string& error);
  /// The capture loop; returns an exit code when the source ends, the frame/duration limit is
  /// reached, `stop` becomes true, or errors persist.
  int run(const std::atomic<bool>& stop);
  /// Bench aid: skips `skip` frames, then captures one and centroids it. The frame stays
  /// acquired until the next call or destruction. Returns 0 or -errno.
  int grab(int skip, frame::FrameView& frame, std::span<const centroid::Blob>& blobs);
  void shutdown();

  /// Counters as JSON (--stats-json).
  std::string stats_json(const std::string& exit_reason, int exit_code) const;
  /// Paced simulated source: whether it kept its schedule ("real time kept ...") or by how much
  /// it fell behind ("NOT real time ..."); empty when the source is not paced.
  std::string realtime_verdict() const;
  const UnitConfig& config() const { return config_; }
  const centroid::CentroidConfig& centroid_config() const { return marks_.config(); }
  const std::string& notes() const { return notes_; }
  /// Why run() returned an error exit code, when it knows more than the code says ("" if not).
  const std::string& stop_reason() const { return stop_reason_; }

 private:
  int setup_camera(InputFactory& inputs, int& width, int& height, std::string& error);
  int process_frame(const frame::FrameView& frame);
  /// The marks of the frame, with the time it took counted; their count or -errno.
  int find_marks(const frame::FrameView& frame, std::uint16_t& flags);
  /// The exposure's trigger sequence and start from the pairing (the frame's own without a
  /// trigger). False when triggered_only and no edge claims the frame.
  bool pair_exposure(const frame::FrameView& frame, ExposureStamp& exposure);
  void note_trigger_error(std::uint64_t count = 1);
  void retry_stopped_trigger();
  void apply_exposure(std::uint32_t exposure_us);
  void service_camera_recovery(time::MonotonicNs now);
  int run_trigger_only(const std::atomic<bool>& stop);
  int drain_edges(int timeout_ms);
  void apply_config_changes();
  void apply_trigger_change(double rate_hz, std::int64_t width_ns);
  void send_health(time::MonotonicNs now);

  UnitConfig config_;
  std::string notes_;
  SimulatedCameraFactory simulated_;
  std::unique_ptr<Camera> camera_;    // null: source none
  CameraRecovery recovery_;           // while the camera is down, no acquire()
  std::unique_ptr<Trigger> trigger_;  // null: trigger none
  TriggerPairing pairing_;
  MarkFinder marks_;
  LinkSet links_;
  health::UnitCounters counters_;
  StatusLatches status_{counters_};  // the error bits a health report must carry once
  UnitRegisters registers_;          // Modbus
  UnitClock clock_;
  std::unique_ptr<health::BoardTemperatureSampler> board_temp_;  // off the capture loop

  msg::MarkObservations obs_{};
  RunCounters run_{};
  time::MonotonicNs start_mono_ns_ = 0;
  time::MonotonicNs last_health_ns_ = 0;
  bool frames_dropped_pending_ = false;
  bool held_ = false;
  frame::FrameView held_frame_{};
  std::string stop_reason_;
};

}  // namespace storetrack::unit
