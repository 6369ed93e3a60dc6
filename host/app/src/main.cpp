// storetrack-host: the host program. Receives MarkObservations (UDP and/or CAN FD), aligns
// exposures across cameras, identifies marks, solves the store pose with its uncertainty
// (ExposureProcessor) and writes every sample to the FTI sinks: iNET-X (first, it is the
// real-time path), Chapter 10 file, CSV. Counters at exit and as JSON (--stats-json).
// Exit codes: 0 ok, 1 runtime failure (sockets, disk), 2 bad arguments or input files.
#include <poll.h>
#include <signal.h>

#include <spdlog/spdlog.h>
#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <cinttypes>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <fstream>
#include <functional>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>
#include <unordered_map>

#include "host_config.hpp"
#include "latency.hpp"
#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"
#include "storetrack/ingest/receivers.hpp"
#include "storetrack/match/mark_matcher.hpp"
#include "storetrack/output/chapter10_writer.hpp"
#include "storetrack/output/csv_writer.hpp"
#include "storetrack/output/inetx.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/pipeline/pose_tracker.hpp"
#include "storetrack/sim/body.hpp"
#include "storetrack/time/time.hpp"

namespace st = storetrack;
using st::hostapp::HostConfig;

namespace {

std::atomic<bool> g_stop{false};
void on_signal(int) {
  g_stop = true;
}

nlohmann::json decode_counters_json(const st::msg::DecodeCounters& c) {
  nlohmann::json j = nlohmann::json::object();
  for (std::size_t i = 1; i < st::msg::kNumDecodeErrors; ++i)
    j[st::msg::to_string(static_cast<st::msg::DecodeError>(i))] = c.by_error[i];
  return j;
}

// File sinks (Chapter 10 with fdatasync, CSV) run on their own thread so a slow disk never
// delays the real-time path (receive -> process -> iNET-X).
class FileWriterThread {
 public:
  template <typename Fn>
  explicit FileWriterThread(Fn&& write)
      : write_(std::forward<Fn>(write)), thread_([this] { run(); }) {}
  ~FileWriterThread() { stop(); }
  void push(const st::msg::FtiSample& s) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      queue_.push_back(s);
      max_depth_ = std::max(max_depth_, queue_.size());
    }
    cv_.notify_one();
  }
  void stop() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (stopping_) return;
      stopping_ = true;
    }
    cv_.notify_one();
    thread_.join();
  }
  std::size_t max_depth() const { return max_depth_; }

 private:
  void run() {
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      cv_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      while (!queue_.empty()) {
        const st::msg::FtiSample s = queue_.front();
        queue_.pop_front();
        lock.unlock();
        write_(s);
        lock.lock();
      }
      if (stopping_) return;
    }
  }
  std::function<void(const st::msg::FtiSample&)> write_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<st::msg::FtiSample> queue_;
  std::size_t max_depth_ = 0;
  bool stopping_ = false;
  std::thread thread_;
};

struct Sinks {
  st::output::InetxSender inetx;
  bool inetx_open = false;
  st::output::Chapter10Writer ch10;
  bool ch10_open = false;
  st::output::FtiCsvWriter csv;
  bool csv_open = false;
  std::FILE* marks = nullptr;
  std::FILE* rigid = nullptr;
  std::atomic<std::uint64_t> write_errors{0};
};

void write_marks_rows(std::FILE* f, const st::pipeline::AlignedExposure& e,
                      const st::pipeline::ExposureResult& r) {
  for (const auto& m : r.marks) {
    const double su = std::sqrt(m.cov_w(0, 0)), sv = std::sqrt(m.cov_w(1, 1)),
                 sw = std::sqrt(m.cov_w(2, 2));
    for (const auto& o : m.observations) {
      double u = NAN, v = NAN;
      for (const auto& cam : e.cameras) {
        if (cam.camera_id == o.camera_id && o.mark_index >= 0 && o.mark_index < cam.mark_count) {
          u = cam.marks[static_cast<std::size_t>(o.mark_index)].x_px;
          v = cam.marks[static_cast<std::size_t>(o.mark_index)].y_px;
        }
      }
      std::fprintf(f,
                   "%" PRIu32 ",%" PRId64
                   ",%d,%c,%d,%.9g,%.9g,%.9g,%.4g,%.4g,%.4g,%d,%.3f,%.3f,%.5f,%.5f,%.4f\n",
                   e.trigger_seq, r.reference_mid_tai_ns, m.id, m.body, m.excluded ? 1 : 0,
                   m.p_w.x(), m.p_w.y(), m.p_w.z(), su, sv, sw, o.camera_id, u, v,
                   o.residual_px.x(), o.residual_px.y(), o.sigma_px);
    }
  }
}

void write_rigid_rows(std::FILE* f, std::uint32_t seq, char body,
                      const st::rigid::RigidCheckResult& c) {
  for (const auto& p : c.pairs) {
    std::fprintf(f, "%" PRIu32 ",%c,%d,%d,%.9g,%.9g,%.4g,%.4g\n", seq, body, p.id_a, p.id_b,
                 p.distance_m, p.surveyed_m, p.sigma_m, p.z2);
  }
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "storetrack-host: exposure alignment, 6-DoF store pose with GUM uncertainty, "
      "FTI output (iNET-X, IRIG 106 Chapter 10, CSV)"};
  HostConfig cfg;
  std::string calibration_path, pylon_path, store_path, config_path, initial_marks_path;
  std::string stats_json_path, ch10_sync = "every", log_level = "info";
  std::vector<std::string> udp_sources;
  double max_wait_ms = 0, duration_s = 0, idle_exit_s = 0;
  std::int64_t expect_exposures = 0;
  int min_cameras = 0;
  bool progress = false;
  app.add_option("--calibration", calibration_path, "Rig calibration JSON")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--pylon-survey", pylon_path, "Pylon mark survey JSON")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--store-survey", store_path, "Store (or pendulum board) mark survey JSON")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--config", config_path, "Host configuration JSON (values CLI options override)")
      ->check(CLI::ExistingFile);
  app.add_option("--initial-marks", initial_marks_path,
                 "Initial mark positions in the world frame (installation survey), JSON")
      ->check(CLI::ExistingFile);
  app.add_option("--udp-port", cfg.udp_port, "UDP port to receive observations on (0: no UDP)")
      ->check(CLI::Range(0, 65535));
  app.add_option("--udp-bind", cfg.udp_bind,
                 "Local address to bind (required with UDP; 0.0.0.0: every interface)");
  app.add_option("--udp-source", udp_sources,
                 "UNIT@a.b.c.d: accept unit UNIT's datagrams from this address only (repeat)");
  app.add_option("--udp-group", cfg.udp_group, "Multicast group to join");
  app.add_option("--udp-interface", cfg.udp_interface, "Interface address for the multicast join");
  app.add_option("--can", cfg.can_interfaces, "SocketCAN interface(s) to receive CAN FD on");
  app.add_option("--max-wait-ms", max_wait_ms, "Aligner: longest wait for missing cameras")
      ->check(CLI::PositiveNumber);
  app.add_option("--min-cameras", min_cameras, "Aligner: fewer cameras -> exposure dropped")
      ->check(CLI::Range(1, 32));
  app.add_option("--ch10", cfg.ch10_path, "IRIG 106 Chapter 10 output file");
  app.add_option("--ch10-sync", ch10_sync, "every: fdatasync each packet; none")
      ->check(CLI::IsMember({"every", "none"}));
  app.add_option("--csv", cfg.csv_path, "CSV of FTI samples");
  app.add_option("--marks-csv", cfg.marks_csv_path, "CSV of per-mark observations and residuals");
  app.add_option("--rigid-csv", cfg.rigid_csv_path, "CSV of rigid-body pair tests");
  app.add_option("--inetx", cfg.inetx_destination, "iNET-X destination address:port");
  app.add_option("--inetx-stream-id", cfg.inetx_stream_id, "iNET-X stream id");
  app.add_option("--duration-s", duration_s, "Stop after this long (0: until signalled)");
  app.add_option("--idle-exit-s", idle_exit_s,
                 "Stop when no observation arrived for this long after the first one");
  app.add_option("--expect-exposures", expect_exposures,
                 "Stop after this many exposures were released (0: no limit)");
  app.add_option("--stats-json", stats_json_path, "Write all counters as JSON at exit");
  app.add_flag("--progress", progress, "Print a progress line every second (stderr)");
  app.add_option("--log-level", log_level, "trace|debug|info|warn|error")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error"}));
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? 0 : 2;
  }
  spdlog::set_level(spdlog::level::from_str(log_level));

  st::camera::RigCalibration rig;
  st::sim::RigidBodySurvey pylon, store;
  try {
    if (!config_path.empty()) st::hostapp::load_host_config(config_path, cfg);
    rig = st::camera::read_rig_calibration(calibration_path);
    pylon = st::sim::read_survey(pylon_path);
    store = st::sim::read_survey(store_path);
    if (!initial_marks_path.empty())
      cfg.initial_marks_w = st::hostapp::load_initial_marks(initial_marks_path);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-host: %s\n", e.what());
    return 2;
  }
  if (rig.cameras.empty() || rig.cameras.size() > 32) {
    std::fprintf(stderr, "storetrack-host: %s: the rig needs 1..32 cameras (has %zu)\n",
                 calibration_path.c_str(), rig.cameras.size());
    return 2;
  }
  if (cfg.udp_port == 0 && cfg.can_interfaces.empty()) {
    std::fprintf(stderr, "storetrack-host: no input: give --udp-port and/or --can\n");
    return 2;
  }
  try {
    if (max_wait_ms > 0) st::hostapp::set_max_wait_ms(cfg, max_wait_ms, "--max-wait-ms");
    if (min_cameras > 0) cfg.aligner.min_cameras = min_cameras;
    for (const auto& text : udp_sources)
      cfg.udp_sources.push_back(st::hostapp::parse_udp_source(text));
    std::vector<int> camera_ids, unit_ids;
    for (const auto& c : rig.cameras) {
      camera_ids.push_back(c.camera_id);
      unit_ids.push_back(c.unit_id);
    }
    st::hostapp::finish_host_config(cfg, camera_ids, unit_ids);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-host: %s\n", e.what());
    return 2;
  }
  cfg.ch10.sync = ch10_sync == "none" ? st::output::Chapter10Sync::kNone
                                      : st::output::Chapter10Sync::kEveryPacket;
  cfg.ch10.stores = {{cfg.processor.store_id, store.name}};

  // Processing chain.
  std::unique_ptr<st::pipeline::ExposureProcessor> processor;
  std::unique_ptr<st::pipeline::PoseTracker> pose_tracker;
  std::unique_ptr<st::ingest::ExposureAligner> aligner;
  try {
    processor = std::make_unique<st::pipeline::ExposureProcessor>(rig, pylon, store, cfg.processor);
    pose_tracker =
        std::make_unique<st::pipeline::PoseTracker>(processor->factors(), cfg.pose_tracker);
    aligner = std::make_unique<st::ingest::ExposureAligner>(cfg.aligner);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-host: bad configuration: %s\n", e.what());
    return 2;
  }
  // Mark identification: the processor's MarkMatcher. Its prior poses (acquisition, and
  // re-acquisition of a body lost for longer than its track gap) are fitted to the installation
  // survey's initial mark positions; without them it cannot acquire a body.
  for (const auto* body : {&pylon, &store}) {
    st::geometry::Transform T_w_b;
    st::geometry::Mat6 cov;
    if (st::match::fit_body_pose(*body, cfg.initial_marks_w, cfg.initial_marks_sigma_m, T_w_b,
                                 cov)) {
      processor->matcher().set_prior_pose(body->name, T_w_b, cov);
    } else {
      spdlog::warn(
          "storetrack-host: no prior pose for '{}' (needs >= 3 non-collinear of its marks in "
          "--initial-marks): its marks cannot be identified",
          body->name);
    }
  }

  // Inputs.
  st::ingest::UdpReceiver udp;
  std::vector<std::unique_ptr<st::ingest::CanFdReceiver>> cans;
  if (cfg.udp_port > 0) {
    const int rc = udp.open(cfg.udp_bind, static_cast<std::uint16_t>(cfg.udp_port), cfg.udp_group,
                            cfg.udp_interface);
    if (rc != 0) {
      std::fprintf(stderr, "storetrack-host: cannot receive UDP on %s:%d%s%s: %s\n",
                   cfg.udp_bind.c_str(), cfg.udp_port, cfg.udp_group.empty() ? "" : " group ",
                   cfg.udp_group.c_str(), std::strerror(-rc));
      return rc == -EINVAL ? 2 : 1;
    }
    for (const auto& src : cfg.udp_sources)
      udp.allow_source(src.unit_id, src.address);  // checked by finish_host_config
    if (cfg.udp_sources.empty())
      spdlog::warn(
          "storetrack-host: no udp.sources configured: datagrams from any sender accepted");
  }
  for (const auto& ifname : cfg.can_interfaces) {
    auto rx = std::make_unique<st::ingest::CanFdReceiver>();
    const int rc = rx->open(ifname);
    if (rc != 0) {
      std::fprintf(stderr, "storetrack-host: cannot open CAN FD interface '%s': %s\n",
                   ifname.c_str(), std::strerror(-rc));
      return rc == -ENODEV ? 2 : 1;
    }
    cans.push_back(std::move(rx));
  }

  // Sinks.
  Sinks sinks;
  if (!cfg.inetx_destination.empty()) {
    const int rc = sinks.inetx.open(cfg.inetx_destination, cfg.inetx_stream_id);
    if (rc != 0) {
      std::fprintf(stderr, "storetrack-host: --inetx '%s': %s\n", cfg.inetx_destination.c_str(),
                   rc == -EINVAL ? "expected a.b.c.d:port" : std::strerror(-rc));
      return rc == -EINVAL ? 2 : 1;
    }
    sinks.inetx_open = true;
  }
  if (!cfg.ch10_path.empty()) {
    const int rc = sinks.ch10.open(cfg.ch10_path, cfg.ch10);
    if (rc != 0) {
      std::fprintf(stderr, "storetrack-host: cannot write Chapter 10 file '%s': %s\n",
                   cfg.ch10_path.c_str(), std::strerror(-rc));
      return 2;
    }
    sinks.ch10_open = true;
  }
  if (!cfg.csv_path.empty()) {
    if (sinks.csv.open(cfg.csv_path) != 0) {
      std::fprintf(stderr, "storetrack-host: cannot write CSV '%s'\n", cfg.csv_path.c_str());
      return 2;
    }
    sinks.csv_open = true;
  }
  if (!cfg.marks_csv_path.empty()) {
    sinks.marks = std::fopen(cfg.marks_csv_path.c_str(), "w");
    if (!sinks.marks) {
      std::fprintf(stderr, "storetrack-host: cannot write '%s'\n", cfg.marks_csv_path.c_str());
      return 2;
    }
    std::fprintf(sinks.marks,
                 "trigger_seq [1],reference_mid_tai_ns [ns],mark_id [1],body [p|s|?],"
                 "excluded [0|1],x_w [m],y_w [m],z_w [m],u_x_w [m],u_y_w [m],u_z_w [m],"
                 "camera_id [1],u_obs [px],v_obs [px],residual_u [px],residual_v [px],"
                 "sigma [px]\n");
  }
  if (!cfg.rigid_csv_path.empty()) {
    sinks.rigid = std::fopen(cfg.rigid_csv_path.c_str(), "w");
    if (!sinks.rigid) {
      std::fprintf(stderr, "storetrack-host: cannot write '%s'\n", cfg.rigid_csv_path.c_str());
      return 2;
    }
    std::fprintf(sinks.rigid,
                 "trigger_seq [1],body [p|s],id_a [1],id_b [1],distance [m],surveyed [m],"
                 "sigma [m],z2 [1]\n");
  }

  FileWriterThread file_writer([&sinks](const st::msg::FtiSample& s) {
    if (sinks.ch10_open && sinks.ch10.write(s) != 0) ++sinks.write_errors;
    if (sinks.csv_open && sinks.csv.write(s) != 0) ++sinks.write_errors;
  });

  signal(SIGINT, on_signal);
  signal(SIGTERM, on_signal);

  // Main loop: one thread, poll() on every input with the aligner's next deadline as timeout.
  st::hostapp::LatencyStats latency_complete, latency_all, latency_processing;
  std::unordered_map<std::uint32_t, st::time::MonotonicNs> last_arrival;
  std::vector<st::pipeline::AlignedExposure> ready;
  std::uint64_t exposures = 0, valid_samples = 0, health_messages = 0;
  std::map<int, nlohmann::json> unit_health;
  const st::time::MonotonicNs t_start = st::time::monotonic_now_ns();
  st::time::MonotonicNs t_first_input = 0, t_last_input = 0, t_last_progress = t_start;
  st::time::MonotonicNs now = t_start;

  auto on_message = [&](const st::msg::AnyMessage& m) {
    if (const auto* obs = std::get_if<st::msg::MarkObservations>(&m)) {
      if (t_first_input == 0) t_first_input = now;
      t_last_input = now;
      last_arrival[obs->trigger_seq] = now;
      aligner->push(*obs, now, ready);
    } else if (const auto* h = std::get_if<st::msg::UnitHealth>(&m)) {
      ++health_messages;
      unit_health[h->unit_id] = {
          {"clock_state", h->clock_state},       {"frames_captured", h->frames_captured},
          {"frames_dropped", h->frames_dropped}, {"observations_sent", h->observations_sent},
          {"link_tx_errors", h->link_tx_errors}, {"status", h->status}};
    }
  };

  auto process_ready = [&]() {
    for (const auto& e : ready) {
      const st::time::MonotonicNs t0 = st::time::monotonic_now_ns();
      st::pipeline::ExposureResult r = processor->process(e);  // matcher + geometry
      pose_tracker->update(r);  // an unsolved T_p_s: extrapolated over a short gap, or invalid
      ++exposures;
      const st::msg::FtiSample& s = r.sample;
      if (s.status & st::msg::fti_status::kValid) ++valid_samples;
      if (sinks.inetx_open) sinks.inetx.send(s);
      const st::time::MonotonicNs t_sent = st::time::monotonic_now_ns();
      latency_processing.add(t_sent - t0);
      if (auto it = last_arrival.find(e.trigger_seq); it != last_arrival.end()) {
        latency_all.add(t_sent - it->second);
        if (e.missing_camera_mask == 0) latency_complete.add(t_sent - it->second);
        last_arrival.erase(it);
      }
      if (sinks.ch10_open || sinks.csv_open) file_writer.push(s);
      if (sinks.marks) write_marks_rows(sinks.marks, e, r);
      if (sinks.rigid) {
        write_rigid_rows(sinks.rigid, e.trigger_seq, 'p', r.pylon_check);
        write_rigid_rows(sinks.rigid, e.trigger_seq, 's', r.store_check);
      }
    }
    ready.clear();
    if (last_arrival.size() > 4096) last_arrival.clear();  // stale entries of dropped exposures
  };

  std::vector<pollfd> fds;
  if (udp.fd() >= 0) fds.push_back({udp.fd(), POLLIN, 0});
  for (const auto& c : cans)
    fds.push_back({c->fd(), POLLIN, 0});
  spdlog::info("storetrack-host: {} cameras, inputs: {}{}, waiting for observations",
               rig.cameras.size(), cfg.udp_port ? fmt::format("udp:{} ", cfg.udp_port) : "",
               cans.empty() ? "" : fmt::format("{} CAN interface(s)", cans.size()));
  int exit_code = 0;
  while (!g_stop) {
    now = st::time::monotonic_now_ns();
    const st::time::MonotonicNs deadline = aligner->next_deadline();
    int timeout_ms = 100;
    if (deadline != INT64_MAX)
      timeout_ms = static_cast<int>(
          std::clamp<std::int64_t>((deadline - now + 999'999) / 1'000'000, 0, 100));
    const int n = ::poll(fds.data(), fds.size(), timeout_ms);
    if (n < 0 && errno != EINTR) {
      spdlog::error("poll: {}", std::strerror(errno));
      exit_code = 1;
      break;
    }
    now = st::time::monotonic_now_ns();
    std::size_t fi = 0;
    if (udp.fd() >= 0) {
      if (fds[fi].revents & POLLIN) udp.receive(on_message);
      ++fi;
    }
    for (auto& c : cans) {
      if (fds[fi].revents & POLLIN)
        c->receive(on_message);
      else
        c->expire(now);
      ++fi;
    }
    aligner->poll(st::time::monotonic_now_ns(), ready);
    process_ready();
    now = st::time::monotonic_now_ns();
    if (progress && now - t_last_progress >= 1'000'000'000) {
      t_last_progress = now;
      std::fprintf(stderr,
                   "\rstoretrack-host: %" PRIu64 " exposures, %" PRIu64 " valid, pending %zu   ",
                   exposures, valid_samples, aligner->pending());
    }
    if (duration_s > 0 && now - t_start >= static_cast<std::int64_t>(duration_s * 1e9)) break;
    if (idle_exit_s > 0 && t_first_input != 0 &&
        now - t_last_input >= static_cast<std::int64_t>(idle_exit_s * 1e9))
      break;
    if (expect_exposures > 0 && static_cast<std::int64_t>(exposures) >= expect_exposures) break;
  }
  aligner->flush(ready);
  process_ready();
  if (progress) std::fprintf(stderr, "\n");
  file_writer.stop();
  if (sinks.ch10_open && sinks.ch10.close() != 0) ++sinks.write_errors;
  if (sinks.csv_open && sinks.csv.close() != 0) ++sinks.write_errors;
  if (sinks.marks) std::fclose(sinks.marks);
  if (sinks.rigid) std::fclose(sinks.rigid);

  // Counters.
  const auto& ac = aligner->counters();
  nlohmann::json stats;
  stats["exposures_processed"] = exposures;
  stats["valid_samples"] = valid_samples;
  stats["wall_time_s"] = static_cast<double>(st::time::monotonic_now_ns() - t_start) * 1e-9;
  const auto& uc = udp.counters();
  stats["udp"] = {{"datagrams", uc.datagrams},
                  {"bytes", uc.bytes},
                  {"decoded", uc.decoded},
                  {"receive_errors", uc.receive_errors},
                  {"datagram_seq_gaps", uc.datagram_seq_gaps},
                  {"spoofed_source", uc.spoofed_source},
                  {"kernel_drops", uc.kernel_drops},
                  {"budget_exhausted", uc.budget_exhausted},
                  {"decode_errors", decode_counters_json(uc.decode_errors)}};
  nlohmann::json can_json = nlohmann::json::array();
  for (std::size_t i = 0; i < cans.size(); ++i) {
    const auto& c = cans[i]->counters();
    const auto& r = cans[i]->reassembly_counters();
    can_json.push_back({{"interface", cfg.can_interfaces[i]},
                        {"frames", c.frames},
                        {"classic_or_bad_frames", c.classic_or_bad_frames},
                        {"decoded", c.decoded},
                        {"receive_errors", c.receive_errors},
                        {"kernel_drops", c.kernel_drops},
                        {"budget_exhausted", c.budget_exhausted},
                        {"decode_errors", decode_counters_json(c.decode_errors)},
                        {"reassembly",
                         {{"completed", r.completed},
                          {"duplicates", r.duplicates},
                          {"crc_errors", r.crc_errors},
                          {"timeouts", r.timeouts},
                          {"evictions", r.evictions},
                          {"fragments_lost", r.fragments_lost}}}});
  }
  stats["can"] = can_json;
  stats["aligner"] = {{"observations_in", ac.observations_in},
                      {"observations_used", ac.observations_used},
                      {"exposures_complete", ac.exposures_complete},
                      {"exposures_partial_timeout", ac.exposures_partial_timeout},
                      {"exposures_partial_overflow", ac.exposures_partial_overflow},
                      {"exposures_dropped_too_few_cameras", ac.exposures_dropped_too_few_cameras},
                      {"dropped_unknown_camera", ac.dropped_unknown_camera},
                      {"dropped_spoofed", ac.dropped_spoofed},
                      {"dropped_invalid", ac.dropped_invalid},
                      {"dropped_time_out_of_range", ac.dropped_time_out_of_range},
                      {"dropped_duplicate", ac.dropped_duplicate},
                      {"dropped_late", ac.dropped_late},
                      {"dropped_time_mismatch", ac.dropped_time_mismatch},
                      {"dropped_quarantined", ac.dropped_quarantined},
                      {"dropped_too_few_cameras", ac.dropped_too_few_cameras},
                      {"sequence_offset_changes", ac.sequence_offset_changes},
                      {"sequence_restarts", ac.sequence_restarts}};
  nlohmann::json cams = nlohmann::json::array();
  for (std::size_t i = 0; i < cfg.aligner.camera_ids.size(); ++i) {
    const auto& c = aligner->camera_counters()[i];
    cams.push_back({{"camera_id", cfg.aligner.camera_ids[i]},
                    {"received", c.received},
                    {"used", c.used},
                    {"missing", c.missing},
                    {"late", c.late},
                    {"duplicate", c.duplicate},
                    {"time_mismatch", c.time_mismatch},
                    {"spoofed", c.spoofed},
                    {"quarantined", c.quarantined},
                    {"offset_changes", c.offset_changes},
                    {"sequence_offset", c.sequence_offset}});
  }
  stats["cameras"] = cams;
  const auto& ic = processor->matcher().counters();
  stats["identifier"] = {{"matcher", "host/match MarkMatcher"},
                         {"exposures", ic.exposures},
                         {"observations", ic.observations},
                         {"identified", ic.identified},
                         {"ambiguous", ic.ambiguous_observation + ic.ambiguous_mark},
                         {"ambiguous_observation", ic.ambiguous_observation},
                         {"ambiguous_mark", ic.ambiguous_mark},
                         {"unmatched", ic.unmatched},
                         {"unknown_camera", ic.unknown_camera},
                         {"bad_observation", ic.bad_observation},
                         {"fallback_sigma", ic.fallback_sigma},
                         {"rejected_by_flags", ic.rejected_by_flags},
                         {"undistort_failed", ic.undistort_failed},
                         {"epipolar_outlier", ic.epipolar_outlier},
                         {"epipolar_rejected", ic.epipolar_rejected},
                         {"layout_rejected", ic.layout_rejected},
                         {"single_view", ic.single_view},
                         {"acquisitions", ic.acquisitions},
                         {"duplicate_camera", ic.duplicate_camera}};
  const auto& pc = processor->counters();
  stats["processor"] = {{"exposures", pc.exposures},
                        {"unknown_camera", pc.unknown_camera},
                        {"bad_observation", pc.bad_observation},
                        {"rejected_by_flags", pc.rejected_by_flags},
                        {"ambiguous_ids", pc.ambiguous_ids},
                        {"too_few_cameras", pc.too_few_cameras},
                        {"triangulation_failed", pc.triangulation_failed},
                        {"marks_excluded", pc.marks_excluded},
                        {"pose_failed", pc.pose_failed},
                        {"degenerate_geometry", pc.degenerate_geometry}};
  const auto& tc = pose_tracker->counters();
  stats["pose_tracker"] = {{"solved", tc.solved},
                           {"extrapolated", tc.extrapolated},
                           {"not_extrapolated", tc.not_extrapolated}};
  const auto& cc = sinks.ch10.counters();
  stats["outputs"] = {{"inetx_sent", sinks.inetx.counters().packets_sent},
                      {"inetx_send_errors", sinks.inetx.counters().send_errors},
                      {"ch10_packets", cc.packets_written},
                      {"ch10_messages", cc.messages_written},
                      {"ch10_time_packets", cc.time_packets},
                      {"ch10_bytes", cc.bytes_written},
                      {"ch10_write_errors", cc.write_errors},
                      {"ch10_sync_errors", cc.sync_errors},
                      {"csv_rows", sinks.csv.rows_written()},
                      {"write_errors", sinks.write_errors.load()},
                      {"file_queue_max_depth", file_writer.max_depth()}};
  stats["latency"] = {{"last_observation_to_inetx_complete_exposures", latency_complete.to_json()},
                      {"last_observation_to_inetx_all_exposures", latency_all.to_json()},
                      {"processing_per_exposure", latency_processing.to_json()}};
  stats["unit_health_messages"] = health_messages;
  nlohmann::json health = nlohmann::json::object();
  for (const auto& [unit, h] : unit_health)
    health[std::to_string(unit)] = h;
  stats["unit_health"] = health;

  std::printf("storetrack-host summary\n");
  std::printf("  observations in/used      %10" PRIu64 " / %" PRIu64 "\n", ac.observations_in,
              ac.observations_used);
  std::printf("  exposures complete/partial %9" PRIu64 " / %" PRIu64 " (dropped %" PRIu64 ")\n",
              ac.exposures_complete, ac.exposures_partial_timeout + ac.exposures_partial_overflow,
              ac.exposures_dropped_too_few_cameras);
  std::printf("  dropped: duplicate %" PRIu64 ", late %" PRIu64 ", time mismatch %" PRIu64
              ", unknown camera %" PRIu64 ", invalid %" PRIu64 "\n",
              ac.dropped_duplicate, ac.dropped_late, ac.dropped_time_mismatch,
              ac.dropped_unknown_camera, ac.dropped_invalid);
  std::printf("  marks identified %" PRIu64 " of %" PRIu64 " (ambiguous %" PRIu64
              ", unmatched %" PRIu64 ")\n",
              ic.identified, ic.observations, ic.ambiguous_observation + ic.ambiguous_mark,
              ic.unmatched);
  std::printf("  samples valid/total        %9" PRIu64 " / %" PRIu64 "\n", valid_samples,
              exposures);
  std::printf(
      "  latency last obs -> iNET-X p50 %.0f us, p99 %.0f us, max %.0f us (%zu complete "
      "exposures)\n",
      static_cast<double>(latency_complete.percentile(0.5)) * 1e-3,
      static_cast<double>(latency_complete.percentile(0.99)) * 1e-3,
      static_cast<double>(latency_complete.max()) * 1e-3, latency_complete.count());
  if (!stats_json_path.empty()) {
    std::ofstream out(stats_json_path);
    out << stats.dump(2) << "\n";
    if (!out) {
      std::fprintf(stderr, "storetrack-host: cannot write '%s'\n", stats_json_path.c_str());
      exit_code = 1;
    }
  }
  if (sinks.write_errors > 0 || cc.write_errors > 0) exit_code = 1;
  return exit_code;
}
