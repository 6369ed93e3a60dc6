// storetrack-trigger-emu: the FTI system's camera trigger on the bench. Drives trigger pulses on
// GPIO lines at a rate, pulse width and jitter, with scripted faults (missing, double, burst),
// and logs every edge it wrote with CLOCK_MONOTONIC times (CSV or JSON) so a bench test can
// compare against what the unit saw. Works on a real chip (libgpiod) and on gpio-sim.
#include <sched.h>
#include <sys/mman.h>

#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>
#include "storetrack/cli/command_line.hpp"

#include "storetrack/time/time.hpp"
#include "storetrack/trigger_emu/line_driver.hpp"
#include "storetrack/trigger_emu/player.hpp"
#include "storetrack/trigger_emu/schedule.hpp"

namespace te = storetrack::trigger_emu;

namespace {

std::atomic<bool> g_stop{false};
extern "C" void on_signal(int) {
  g_stop.store(true);
}

bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() &&
         s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

}  // namespace

int main(int argc, char** argv) {
  storetrack::cli::Command app{
      "storetrack-trigger-emu: bench camera-trigger emulator (libgpiod / gpio-sim).\n"
      "Plays --count nominal pulses at --rate-hz with scripted faults and logs what it sent."};
  std::string chip;
  std::vector<unsigned> lines{0};
  std::string backend = "gpiod";
  std::string sim_sysfs;
  te::ScheduleConfig config;
  double width_us = 1000.0;
  double jitter_us = 0.0;
  double start_delay_ms = 100.0;
  std::vector<int> missing;
  std::vector<int> doubles;
  std::vector<int> bursts;
  int burst_count = 3;
  double double_gap_us = 0.0;
  double burst_gap_us = 0.0;
  std::string script_path;
  std::string log_path;
  std::string log_format = "auto";
  bool active_low = false;
  bool dry_run = false;
  int rt_priority = 0;

  app.option("-c,--chip", chip, "GPIO chip: name (gpiochip0), path, label or number");
  app.option("-l,--lines", lines, "line offsets, all pulsed together").delimiter(',');
  app.option("-b,--backend", backend,
             "gpiod: request the lines as outputs (real wiring); sim-pull: drive a gpio-sim "
             "chip's lines from outside through sysfs sim_gpioN/pull (the unit reads them)")
      .one_of({"gpiod", "sim-pull"});
  app.option("--sim-sysfs", sim_sysfs,
             "sim-pull: the chip's sysfs directory (default /sys/bus/gpio/devices/<chip>)");
  app.option("-r,--rate-hz", config.rate_hz, "nominal trigger rate").show_default();
  app.option("-w,--width-us", width_us, "pulse width").show_default();
  app.option("-j,--jitter-us", jitter_us, "rising edges uniform in +-jitter of nominal")
      .show_default();
  app.option("-n,--count", config.count, "nominal pulses").show_default();
  app.option("--seed", config.seed, "jitter random seed").show_default();
  app.option("--missing", missing, "nominal pulse indices not sent").delimiter(',');
  app.option("--double", doubles, "indices followed by one extra pulse").delimiter(',');
  app.option("--double-gap-us", double_gap_us, "rise-to-rise gap of a double (0: 2 x width)");
  app.option("--burst", bursts, "indices followed by --burst-count extra pulses").delimiter(',');
  app.option("--burst-count", burst_count, "extra pulses per burst").show_default();
  app.option("--burst-gap-us", burst_gap_us, "rise-to-rise gap in a burst (0: 2 x width)");
  app.option("--script", script_path,
             "JSON fault script {\"faults\":[{\"kind\":\"burst\",\"at\":9,\"count\":4,"
             "\"gap_us\":300}]}")
      .existing_file();
  app.option("--log", log_path, "write what was sent (CLOCK_MONOTONIC ns) to this file");
  app.option("--log-format", log_format, "csv, json or auto (by file extension)")
      .one_of({"auto", "csv", "json"});
  app.option("--start-delay-ms", start_delay_ms, "wait before the first pulse").show_default();
  app.flag("--active-low", active_low, "asserted = electrically low");
  app.option("--rt-priority", rt_priority, "SCHED_FIFO priority (needs CAP_SYS_NICE); 0 off");
  app.flag("--dry-run", dry_run, "print the schedule, touch no GPIO");
  if (const int rc = app.parse(argc, argv); rc >= 0) return rc;

  try {
    config.pulse_width_ns = static_cast<std::int64_t>(width_us * 1e3);
    config.jitter_ns = static_cast<std::int64_t>(jitter_us * 1e3);
    if (!script_path.empty()) {
      std::ifstream in(script_path);
      config.faults = te::parse_fault_script(nlohmann::json::parse(in));
    }
    for (int i : missing)
      config.faults.push_back({te::FaultKind::kMissing, i, 1, 0});
    for (int i : doubles) {
      config.faults.push_back(
          {te::FaultKind::kDouble, i, 1, static_cast<std::int64_t>(double_gap_us * 1e3)});
    }
    for (int i : bursts) {
      config.faults.push_back(
          {te::FaultKind::kBurst, i, burst_count, static_cast<std::int64_t>(burst_gap_us * 1e3)});
    }
    const std::vector<te::ScheduledPulse> schedule = te::make_schedule(config);

    if (log_format == "auto") log_format = ends_with(log_path, ".json") ? "json" : "csv";
    auto write_log = [&](const std::vector<te::SentPulse>& log) {
      if (log_path.empty()) return;
      std::ofstream out(log_path);
      if (log_format == "json") {
        out << te::log_to_json(config, log).dump(1) << '\n';
      } else {
        te::write_log_csv(out, log);
      }
      if (!out) throw std::runtime_error("cannot write log " + log_path);
    };

    if (dry_run) {
      std::vector<te::SentPulse> planned;
      for (const auto& p : schedule)
        planned.push_back({p, p.rise_offset_ns, 0, 0});
      if (log_path.empty()) {
        te::write_log_csv(std::cout, planned);
      } else {
        write_log(planned);
      }
      return 0;
    }
    if (chip.empty()) throw std::invalid_argument("--chip is required (except with --dry-run)");

    std::unique_ptr<te::LineDriver> driver;
    if (backend == "gpiod") {
      driver = std::make_unique<te::GpiodLineDriver>(chip, lines, active_low);
    } else {
      if (sim_sysfs.empty()) sim_sysfs = te::SimPullLineDriver::sysfs_dir_for_chip(chip);
      driver = std::make_unique<te::SimPullLineDriver>(sim_sysfs, lines, active_low);
    }
    if (rt_priority > 0) {
      sched_param sp{};
      sp.sched_priority = rt_priority;
      if (sched_setscheduler(0, SCHED_FIFO, &sp) != 0) {
        std::cerr << "trigger-emu: SCHED_FIFO refused (" << std::strerror(errno)
                  << "), running with normal priority\n";
      }
      mlockall(MCL_CURRENT | MCL_FUTURE);
    }
    std::signal(SIGINT, on_signal);
    std::signal(SIGTERM, on_signal);

    const std::int64_t start =
        storetrack::time::monotonic_now_ns() + static_cast<std::int64_t>(start_delay_ms * 1e6);
    const te::PlayResult result = te::play(*driver, schedule, start, g_stop);
    driver.reset();
    write_log(result.log);

    const te::Lateness late = te::lateness(result.log);
    int withheld = 0;
    int extra = 0;
    for (const auto& s : result.log) {
      withheld += s.pulse.kind == te::PulseKind::kMissing;
      extra += s.pulse.kind == te::PulseKind::kDouble || s.pulse.kind == te::PulseKind::kBurst;
    }
    nlohmann::json summary = {{"sent", late.sent},
                              {"missing", withheld},
                              {"extra", extra},
                              {"start_mono_ns", start},
                              {"mean_late_ns", late.mean_ns},
                              {"max_late_ns", late.max_ns},
                              {"interrupted", result.interrupted},
                              {"error", result.error == 0 ? "" : std::strerror(-result.error)}};
    std::cout << summary.dump() << std::endl;
    if (result.error != 0) {
      std::cerr << "trigger-emu: line write failed: " << std::strerror(-result.error) << '\n';
      return 1;
    }
    return result.interrupted ? 130 : 0;
  } catch (const std::exception& e) {
    std::cerr << "storetrack-trigger-emu: " << e.what() << '\n';
    return 2;
  }
}
