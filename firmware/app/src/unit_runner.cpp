#include "unit_runner.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <ctime>

#include "input/camera.hpp"
#include "input/input_factory.hpp"
#include "input/trigger.hpp"
#include "stats/unit_stats.hpp"

namespace storetrack::unit {

UnitRunner::UnitRunner(UnitConfig config, SimulatedCameraFactory simulated)
    : config_(std::move(config)), simulated_(std::move(simulated)) {}

UnitRunner::~UnitRunner() {
  shutdown();
}

// The camera: made, started, its size known, the clock told whether it keeps its own time.
int UnitRunner::setup_camera(InputFactory& inputs, int& width, int& height, std::string& error) {
  CameraFacts facts;
  if (const int rc = inputs.make_camera(camera_, facts, error); rc != kExitOk) return rc;
  width = facts.width;
  height = facts.height;
  if (facts.clock_state) clock_.configure(config_.clock_state, facts.clock_state);
  clock_.configure_time(config_.time, facts.clock_sigma_ns,
                        config_.ptp4l.uncertainty.holdover_drift_ppb);
  if (config_.unit_id < 0) config_.unit_id = 0;
  if (config_.camera_id < 0) config_.camera_id = 0;
  recovery_.configure(config_.camera_reopen_first_ms, config_.camera_reopen_max_ms);
  if (camera_) {
    const int rc = camera_->start();
    if (rc < 0) {
      error =
          std::string("cannot start frame source ") + camera_->name() + ": " + camera_->error(rc);
      return kExitStartFailure;
    }
    camera_->started_size(width, height);
    if (const std::string notes = camera_->notes(); !notes.empty())
      notes_ += std::string(camera_->name()) + ": " + notes + "\n";
  }
  clock_.follow_source(camera_ ? camera_->fixed_tai_minus_mono_ns() : std::nullopt);
  if (camera_ && !frame_fits_message(width, height, error)) return kExitUsage;
  return kExitOk;
}

// Each part in turn; the first that cannot start says why. Everything the loop needs is
// allocated here.
int UnitRunner::setup(std::string& error) {
  start_mono_ns_ = time::monotonic_now_ns();
  clock_.configure(config_.clock_state, std::nullopt);
  InputFactory inputs(config_, simulated_);
  int width = 0;
  int height = 0;
  if (const int rc = setup_camera(inputs, width, height, error); rc != kExitOk) return rc;

  // --- holding registers from the configuration ------------------------------------------------
  registers_.load(config_, width, height);

  // --- centroider ------------------------------------------------------------------------------
  if (camera_ && !marks_.configure(config_.centroid, width, height, error)) return kExitUsage;

  // --- trigger ---------------------------------------------------------------------------------
  if (!pairing_.configure(config_.trigger, error)) return kExitUsage;
  const auto period = static_cast<std::int64_t>(std::llround(1e9 / config_.trigger.rate_hz));
  if (const int rc = inputs.make_trigger(period, trigger_, error); rc != kExitOk) return rc;
  if (trigger_ && config_.trigger.mode != TriggerMode::kSim) pairing_.start(0);
  if (!config_.trigger.edges_csv.empty() &&
      !pairing_.edge_log().open(config_.trigger.edges_csv, error))
    return kExitStartFailure;

  // --- links -----------------------------------------------------------------------------------
  if (!links_.open(config_, error)) return kExitStartFailure;

  // --- clock ------------------------------------------------------------------------------------
  if (!clock_.start_monitor(config_, error)) return kExitStartFailure;

  // --- Modbus ----------------------------------------------------------------------------------
  if (!registers_.start_server(config_, counters_, error)) return kExitStartFailure;
  std::uint16_t status = msg::unit_status::kCapturing;
  if (config_.maintenance) status |= msg::unit_status::kMaintenanceMode;
  if (trigger_ && trigger_->line().is_master() && config_.trigger.mode != TriggerMode::kSim) {
    status |= msg::unit_status::kTriggerMaster;
  }
  counters_.status.store(status);
  clock_.publish(counters_);
  board_temp_ = std::make_unique<health::BoardTemperatureSampler>(
      config_.board_temp_root, config_.health_period_ms, counters_.board_temp_cdeg);
  board_temp_->start();
  last_health_ns_ = time::monotonic_now_ns();
  return kExitOk;
}

// A trigger line that failed (an edge read, a pulse not driven): counted, flagged in the health
// status until a report carried it; the line itself retries and requests its lines again.
void UnitRunner::note_trigger_error(std::uint64_t count) {
  run_.trigger_errors += count;
  status_.raise_trigger_error();
}

// Failed reads are counted by the pairing and flagged here (trigger_error status bit).
int UnitRunner::drain_edges(int timeout_ms) {
  if (!trigger_) return 0;
  const std::uint64_t errors_before = pairing_.read_errors();
  const int rc = pairing_.drain(*trigger_, timeout_ms);
  if (pairing_.read_errors() != errors_before)
    note_trigger_error(pairing_.read_errors() - errors_before);
  return rc;
}

// A master whose generator could not be started again after a failed change (its GPIO chip
// away): nothing drives the rig's trigger, so it is tried again once a second until it runs,
// the trigger_error bit held meanwhile.
void UnitRunner::retry_stopped_trigger() {
  if (!trigger_) return;
  switch (trigger_->retry_stopped()) {
    case TriggerRetry::kNothingToDo:
      break;
    case TriggerRetry::kStillDown:
      note_trigger_error();
      break;
    case TriggerRetry::kRunning:
      ++run_.trigger_restarts;
      break;
  }
}

void UnitRunner::apply_config_changes() {
  retry_stopped_trigger();
  // Maintenance-mode reconfiguration: may allocate (rare, operator-driven, not per frame).
  RegisterSettings wanted;
  if (!registers_.take_changes(config_, wanted)) return;
  const int threshold = wanted.threshold_dn;
  if (marks_.configured() && threshold != marks_.config().threshold_dn) {
    if (marks_.set_threshold(threshold))
      config_.centroid = marks_.config();
    else
      ++run_.config_apply_errors;  // the table's range check makes this unreachable
  }
  if (wanted.exposure_us != config_.exposure_us) apply_exposure(wanted.exposure_us);
  apply_trigger_change(wanted.trigger_rate_hz, wanted.pulse_width_ns);
  config_.roi_x = wanted.roi_x;
  config_.roi_y = wanted.roi_y;
  config_.roi_width = wanted.roi_width;
  config_.roi_height = wanted.roi_height;
}

// A new exposure, written to the camera's exposure control when one is configured. Refused: the
// change is counted and the camera keeps its exposure. Clamped by the driver (VIDIOC_S_CTRL may
// take the closest valid value instead of refusing): the unit reports and stamps what the
// camera does, not what was asked, and the holding register shows it.
void UnitRunner::apply_exposure(std::uint32_t exposure_us) {
  std::uint32_t applied_us = exposure_us;
  switch (camera_ ? camera_->set_exposure_us(exposure_us, applied_us) : ExposureChange::kApplied) {
    case ExposureChange::kApplied:
      config_.exposure_us = applied_us;
      break;
    case ExposureChange::kRefused:
      ++run_.config_apply_errors;
      std::fprintf(stderr, "storetrack-unit: exposure %u us not applied: %s\n", exposure_us,
                   camera_->error(0).c_str());
      registers_.show_exposure(config_.exposure_us);
      break;
    case ExposureChange::kClamped:
      ++run_.config_apply_errors;
      config_.exposure_us = applied_us;
      std::fprintf(stderr, "storetrack-unit: exposure %u us clamped by the driver to %u us\n",
                   exposure_us, config_.exposure_us);
      registers_.show_exposure(config_.exposure_us);
      break;
  }
}

// A new trigger rate or pulse width. On a gpio master the generator is restarted with it; if
// the new one does not start, the old one is started again (the rig must keep its trigger) and
// the change is counted as not applied.
void UnitRunner::apply_trigger_change(double rate_hz, std::int64_t width_ns) {
  if (rate_hz == config_.trigger.rate_hz && width_ns == config_.trigger.pulse_width_ns) return;
  switch (trigger_ ? trigger_->change(rate_hz, width_ns) : TriggerChange::kApplied) {
    case TriggerChange::kApplied:
      break;
    case TriggerChange::kInvalid:
    case TriggerChange::kKeptPrevious:
      ++run_.config_apply_errors;
      return;
    case TriggerChange::kPreviousNotRunning:
      ++run_.config_apply_errors;
      ++run_.trigger_restart_failures;  // retried by retry_stopped_trigger() until it runs
      note_trigger_error();
      return;
  }
  config_.trigger.rate_hz = rate_hz;
  config_.trigger.pulse_width_ns = width_ns;
  pairing_.change_rate(rate_hz);
}

int UnitRunner::process_frame(const frame::FrameView& frame) {
  ++run_.frames;
  health::UnitCounters::add(counters_.frames_captured);
  // Frame drops: V4L2 sequence gaps, or gaps in a simulated/replayed source's sequence.
  const std::uint64_t dropped_now = camera_->frames_lost_before(frame);
  if (dropped_now > 0) {
    health::UnitCounters::add(counters_.frames_dropped, dropped_now);
    frames_dropped_pending_ = true;
  }

  // triggered_only: a frame no edge can claim is not centroided at all (the free-running
  // source's frames between triggers: most of them; centroiding them would only cost time).
  if (config_.trigger.triggered_only && trigger_ && !trigger_->follows_frames()) {
    drain_edges(0);
    if (!pairing_.edge_in_window(frame.timestamp_mono_ns, false)) {
      ++run_.skipped_untriggered;
      return 0;
    }
  }

  std::uint16_t flags = 0;
  if (frames_dropped_pending_) flags |= msg::exposure_flags::kFramesDroppedBefore;
  const int n = find_marks(frame, flags);
  if (n < 0) return n;
  ++run_.frames_processed;
  // triggered_only: a frame without marks is not a triggered frame (the free-running source's
  // dark frames between triggers); it must not claim an edge.
  if (config_.trigger.triggered_only && n == 0) {
    ++run_.skipped_no_marks;
    return 0;
  }
  ExposureStamp exposure;
  exposure.flags = flags;
  if (!pair_exposure(frame, exposure)) return 0;
  run_.marks += static_cast<std::uint64_t>(n);
  counters_.marks_last_frame.store(static_cast<std::uint32_t>(n), std::memory_order_relaxed);

  exposure.unit_id = static_cast<std::uint8_t>(config_.unit_id);
  exposure.camera_id = static_cast<std::uint8_t>(config_.camera_id);
  exposure.start_tai_ns = clock_.exposure_start_tai_ns(*camera_, frame, exposure.start_mono_ns);
  exposure.duration_ns = frame.exposure_ns != 0 ? frame.exposure_ns : config_.exposure_us * 1000u;
  // The state when this exposure is processed, a few ms after it: the monitor's resolution is
  // its poll period (docs/reliability.md, "Clock").
  exposure.clock_state = clock_.state();
  // At the live monotonic time, a few ms after the exposure (a replayed frame's stamp is the
  // recording's): at 1 ppm holdover growth that is a few ns.
  exposure.time_sigma_ns = clock_.exposure_time_sigma_ns(time::monotonic_now_ns());
  fill_mark_message(exposure, frame, marks_.marks(n), obs_);
  if (links_.send(obs_)) frames_dropped_pending_ = false;
  return 0;
}

int UnitRunner::find_marks(const frame::FrameView& frame, std::uint16_t& flags) {
  const SearchRegion region{config_.roi_x, config_.roi_y, config_.roi_width, config_.roi_height};
  const int n = marks_.find(frame, region, flags);
  const double us = marks_.last_time_us();
  run_.centroid_us_sum += us;
  run_.centroid_us_max = std::max(run_.centroid_us_max, us);
  health::UnitCounters::max(counters_.centroid_time_us_max, static_cast<std::uint32_t>(us));
  if (n < 0) {
    ++run_.centroid_errors;
    health::UnitCounters::add(counters_.centroid_errors);
    status_.raise_centroid_error();
  }
  return n;
}

bool UnitRunner::pair_exposure(const frame::FrameView& frame, ExposureStamp& exposure) {
  exposure.trigger_seq = frame.sequence;
  exposure.start_mono_ns = frame.timestamp_mono_ns;
  if (!trigger_) return true;
  if (trigger_->follows_frames()) {
    // A unit started mid-run counts its trigger edges from 0, as a restarted unit does,
    // unless it kept the rig's numbering.
    pairing_.lead(
        *trigger_, frame.timestamp_mono_ns,
        config_.sim.start_exposure > 0 && !config_.sim.keep_numbering ? 0u : frame.sequence);
  }
  drain_edges(0);
  if (config_.trigger.triggered_only && !pairing_.edge_in_window(frame.timestamp_mono_ns, true)) {
    ++run_.skipped_untriggered;
    return false;
  }
  trigger::PairResult pr;
  pairing_.pair(frame.timestamp_mono_ns, pr);
  exposure.trigger_seq = pr.trigger_seq;
  exposure.start_mono_ns = pr.exposure_start_mono_ns;
  if (!pr.matched) exposure.flags |= msg::exposure_flags::kTriggerMissing;
  if (config_.trigger.triggered_only && !pr.matched) {
    ++run_.skipped_untriggered;
    return false;
  }
  const trigger::PairerCounters& pc = pairing_.counters();
  counters_.triggers_seen.store(pc.edges_seen, std::memory_order_relaxed);
  counters_.triggers_missing.store(pc.frames_unmatched, std::memory_order_relaxed);
  counters_.triggers_extra.store(pc.edges_unmatched + pc.edges_extra, std::memory_order_relaxed);
  return true;
}

void UnitRunner::send_health(time::MonotonicNs now) {
  links_.service(counters_);
  if (trigger_) {
    if (const std::uint64_t pulse_errors = trigger_->new_pulse_errors(); pulse_errors > 0)
      note_trigger_error(pulse_errors);
  }
  clock_.publish(counters_);
  clock_.refresh_offset();
  HealthHeader header;
  header.unit_id = static_cast<std::uint8_t>(config_.unit_id);
  header.clock_state = clock_.published_state();
  header.uptime_s = static_cast<std::uint32_t>((now - start_mono_ns_) / time::kNsPerSecond);
  header.report_tai_ns = now + clock_.tai_minus_mono_ns();
  links_.send(health_message(header, counters_));
  ++run_.health_sent;
  last_health_ns_ = now;
  status_.reported(!recovery_.down());
}

int UnitRunner::run_trigger_only(const std::atomic<bool>& stop) {
  const time::MonotonicNs deadline =
      config_.duration_s > 0 ? start_mono_ns_ + static_cast<std::int64_t>(config_.duration_s * 1e9)
                             : 0;
  while (!stop.load(std::memory_order_relaxed)) {
    apply_config_changes();
    if (const int rc = drain_edges(100); rc < 0 && rc != -EAGAIN && rc != -EINTR) {
      const timespec ts{0, 10'000'000};  // counted; the line retries: do not spin meanwhile
      nanosleep(&ts, nullptr);
    }
    const trigger::PairerCounters& pc = pairing_.counters();
    counters_.triggers_seen.store(pc.edges_seen, std::memory_order_relaxed);
    counters_.triggers_extra.store(pc.edges_extra, std::memory_order_relaxed);
    const time::MonotonicNs now = time::monotonic_now_ns();
    if (now - last_health_ns_ >= std::int64_t{config_.health_period_ms} * 1'000'000)
      send_health(now);
    if (config_.frames > 0 && static_cast<long>(pairing_.edges_read()) >= config_.frames) break;
    if (deadline != 0 && now >= deadline) break;
  }
  send_health(time::monotonic_now_ns());
  return kExitOk;
}

// While the camera is down: wait for the next try without spinning (edges, gpio slave or master,
// are still drained), then try.
void UnitRunner::service_camera_recovery(time::MonotonicNs now) {
  if (const int wait_ms = recovery_.wait_ms(now); wait_ms > 0) {
    if (trigger_ && !trigger_->follows_frames()) {
      drain_edges(wait_ms);
    } else {
      const timespec ts{0, wait_ms * 1'000'000L};
      nanosleep(&ts, nullptr);
    }
    return;
  }
  recovery_.try_restart(*camera_, now);
}

int UnitRunner::run(const std::atomic<bool>& stop) {
  if (!camera_) return run_trigger_only(stop);
  const time::MonotonicNs deadline =
      config_.duration_s > 0 ? start_mono_ns_ + static_cast<std::int64_t>(config_.duration_s * 1e9)
                             : 0;
  // Consecutive frames whose processing failed (centroiding, encoding): a unit that cannot
  // process any frame stops. Camera faults never count here: they are recovered from.
  int consecutive_errors = 0;
  int exit_code = kExitOk;
  while (!stop.load(std::memory_order_relaxed)) {
    apply_config_changes();
    if (recovery_.down()) {
      service_camera_recovery(time::monotonic_now_ns());
    } else {
      frame::FrameView frame;
      const int rc = camera_->acquire(frame, 100);
      if (rc == 0) {
        const int prc = process_frame(frame);
        if (camera_->release(frame) < 0) ++run_.release_errors;
        consecutive_errors = prc < 0 ? consecutive_errors + 1 : 0;
        if (consecutive_errors > config_.max_consecutive_errors) {
          exit_code = kExitRuntimeError;
          stop_reason_ = "processing errors: " + std::to_string(consecutive_errors) +
                         " consecutive frames not processed (run.max_consecutive_errors " +
                         std::to_string(config_.max_consecutive_errors) + ")";
          break;
        }
      } else if (rc == -ENODATA) {
        break;  // finite source (sim, replay) ended
      } else if (rc == -EBADMSG) {
        ++run_.frames_corrupt;  // one frame lost, given back by the source
        status_.raise_camera_error();
      } else if (rc != -EAGAIN) {
        ++run_.source_errors;
        status_.raise_camera_error();
        recovery_.failed(*camera_, rc, time::monotonic_now_ns());
      }
      if (trigger_ && !trigger_->follows_frames() && rc == -EAGAIN) drain_edges(0);
    }
    const time::MonotonicNs now = time::monotonic_now_ns();
    if (now - last_health_ns_ >= std::int64_t{config_.health_period_ms} * 1'000'000)
      send_health(now);
    if (config_.frames > 0 && static_cast<long>(run_.frames) >= config_.frames) break;
    if (deadline != 0 && now >= deadline) break;
  }
  recovery_.close(time::monotonic_now_ns());
  counters_.status.fetch_and(static_cast<std::uint16_t>(~msg::unit_status::kCapturing));
  send_health(time::monotonic_now_ns());  // final report with the closing counters
  return exit_code;
}

int UnitRunner::grab(int skip, frame::FrameView& frame, std::span<const centroid::Blob>& blobs) {
  if (!camera_) return -ENODEV;
  if (held_) {
    camera_->release(held_frame_);
    held_ = false;
  }
  for (int i = 0;; ++i) {
    int rc;
    int tries = 0;
    do {
      rc = camera_->acquire(frame, 1000);
    } while (rc == -EAGAIN && ++tries < 10);
    if (rc < 0) return rc;
    if (i >= skip) break;
    camera_->release(frame);
  }
  held_ = true;
  held_frame_ = frame;
  std::uint16_t flags = 0;
  const int n = marks_.find(frame, SearchRegion{}, flags);
  if (n < 0) return n;
  blobs = marks_.marks(n);
  return 0;
}

void UnitRunner::shutdown() {
  registers_.stop();
  clock_.stop();
  if (board_temp_) board_temp_->stop();
  if (held_ && camera_) {
    camera_->release(held_frame_);
    held_ = false;
  }
  if (trigger_) trigger_->line().stop();
  if (camera_) camera_->stop();
  links_.close();
  pairing_.edge_log().close();
}

std::string UnitRunner::realtime_verdict() const {
  return unit::realtime_verdict(camera_ ? camera_->pacing() : std::nullopt, run_.frames);
}

std::string UnitRunner::stats_json(const std::string& exit_reason, int exit_code) const {
  const double duration_s = static_cast<double>(time::monotonic_now_ns() - start_mono_ns_) / 1e9;
  return unit_stats_json({config_, run_, counters_, duration_s, camera_.get(), recovery_.counters(),
                          trigger_.get(), pairing_, marks_, clock_, links_, registers_},
                         exit_reason, exit_code);
}
}  // namespace storetrack::unit
