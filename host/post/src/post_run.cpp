#include "post_run.hpp"

#include <spdlog/spdlog.h>
#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "differences.hpp"
#include "health_history.hpp"
#include "host_options.hpp"
#include "host_setup.hpp"
#include "product_csv.hpp"
#include "recording.hpp"
#include "replay.hpp"
#include "report_files.hpp"
#include "reprocessed_recording.hpp"
#include "same_rig.hpp"
#include "sample_compare.hpp"
#include "smoothed_csv.hpp"
#include "smoothed_differences.hpp"
#include "stats.hpp"
#include "storetrack/json/text_file.hpp"
#include "storetrack/output/csv_writer.hpp"

namespace storetrack::post {

namespace {

using output::RecordedInputKind;

// Bad input (exit 2): the message names the file.
struct InputError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// The recorded command line (RecordedInputKind::kCommandLine): each argument followed by a NUL.
std::vector<std::string> split_command_line(const ch10read::RecordedInput& in,
                                            const std::string& file) {
  std::vector<std::string> args;
  std::string arg;
  for (const std::uint8_t b : in.bytes) {
    if (b == 0) {
      args.push_back(std::move(arg));
      arg.clear();
    } else {
      arg.push_back(static_cast<char>(b));
    }
  }
  if (!arg.empty() || args.empty())
    throw InputError(file + ": the recorded command line is not a list of NUL-ended arguments");
  return args;
}

// The host's options as the live run parsed them (the files it names need not exist here),
// with the substitutes' paths in place of the recorded ones.
hostapp::HostOptions recorded_host_options(const Recording& r, const PostOptions& p) {
  const std::string& first = r.files.front();
  const auto* recorded = find_input(r, static_cast<int>(RecordedInputKind::kCommandLine));
  if (!recorded) throw InputError(first + ": no recorded command line in its inputs");
  std::vector<std::string> args = split_command_line(*recorded, first);
  std::vector<char*> argv;
  for (std::string& a : args)
    argv.push_back(a.data());
  argv.push_back(nullptr);
  hostapp::HostOptions o;
  if (hostapp::parse_host_options(static_cast<int>(args.size()), argv.data(), o,
                                  hostapp::InputFileCheck::kNone) >= 0)
    throw InputError(first + ": the recorded command line does not parse (above)");
  o.command_line = std::move(args);
  o.cfg.rigid_csv_path.clear();  // the host's diagnostic output, not the replay's
  if (!p.calibration_path.empty()) o.calibration_path = p.calibration_path;
  if (!p.pylon_path.empty()) o.pylon_path = p.pylon_path;
  if (!p.store_path.empty()) o.store_path = p.store_path;
  if (!p.config_path.empty()) o.config_path = p.config_path;
  return o;
}

// Each input from disk when the options substitute it, else its recorded bytes.
hostapp::InputReader make_input_reader(const Recording& r, const PostOptions& p) {
  const std::map<RecordedInputKind, std::string> substitutes{
      {RecordedInputKind::kCalibration, p.calibration_path},
      {RecordedInputKind::kPylonSurvey, p.pylon_path},
      {RecordedInputKind::kStoreSurvey, p.store_path},
      {RecordedInputKind::kHostConfig, p.config_path}};
  return [&r, substitutes](RecordedInputKind kind, const std::string& path) -> std::string {
    if (const auto it = substitutes.find(kind); it != substitutes.end() && !it->second.empty())
      return jsonfile::read_text_file(it->second);
    const auto* recorded = find_input(r, static_cast<int>(kind));
    if (!recorded)
      throw InputError(r.files.front() + ": the recorded command line names the " +
                       output::to_string(kind) + " '" + path +
                       "', which the recording does not carry");
    return {recorded->bytes.begin(), recorded->bytes.end()};
  };
}

// A new file only (never over an existing one, a recording least of all).
std::FILE* create_output(const std::string& path) {
  std::string created;
  std::FILE* f = output::fopen_new_file(path, false, created);
  if (!f)
    throw InputError(path + ": " +
                     (errno == EEXIST ? std::string("exists; storetrack-post writes new files only")
                                      : std::string(std::strerror(errno))));
  return f;
}

void print_summary(const Recording& r, const ReplayCounters& c, std::size_t samples) {
  std::printf(
      "storetrack-post: %zu file(s), %llu raw records: %llu observations replayed, %llu refused "
      "live, %llu undecodable, %llu health, %llu deadline checks, %llu flush; %llu exposures, %zu "
      "samples "
      "(%llu withheld)\n",
      r.files.size(), static_cast<unsigned long long>(c.records),
      static_cast<unsigned long long>(c.observations),
      static_cast<unsigned long long>(c.refused_live),
      static_cast<unsigned long long>(c.undecodable),
      static_cast<unsigned long long>(c.health_messages),
      static_cast<unsigned long long>(c.deadline_events),
      static_cast<unsigned long long>(c.flush_events), static_cast<unsigned long long>(c.exposures),
      samples, static_cast<unsigned long long>(c.withheld.total()));
  if (c.flush_events == 0)
    std::printf(
        "storetrack-post: no final flush recorded (the host did not end normally): "
        "%llu exposure(s) left pending, as live\n",
        static_cast<unsigned long long>(c.pending_at_end));
}

// --verify: true when every sample is identical and the counts agree. A recording that ends
// before the host did (torn, or without the final flush: a host killed or crashed) lost the
// samples and records in flight: the samples both hold are compared, the counts cannot agree
// and are reported.
bool report_comparison(const SampleComparison& c, bool ended_early) {
  std::printf("verify: %zu replayed, %zu recorded: %zu identical, %zu different\n", c.replayed,
              c.recorded, c.identical, c.different);
  for (const SampleDifference& d : c.first_differences)
    std::printf(
        "  sample %zu (trigger_seq %u replayed, %lld recorded; %s packet at %zu): first "
        "difference at byte %zu\n",
        d.index, d.replayed_trigger_seq, static_cast<long long>(d.recorded_trigger_seq),
        d.file.c_str(), d.packet_offset, d.first_byte);
  if (c.replayed != c.recorded)
    std::printf("  sample counts differ%s\n",
                ended_early ? " (the recording ends before the host did: only the samples both "
                              "hold are compared)"
                            : "");
  return c.different == 0 && (c.replayed == c.recorded || ended_early);
}

nlohmann::json stats_json(const Recording& r, const ReplayCounters& c, std::size_t samples,
                          const SampleComparison* compared) {
  nlohmann::json j;
  j["files"] = r.files;
  j["torn"] = r.torn;
  j["gaps"] = r.gaps;
  j["replay"] = {{"records", c.records},
                 {"observations", c.observations},
                 {"refused_live", c.refused_live},
                 {"undecodable", c.undecodable},
                 {"health_messages", c.health_messages},
                 {"deadline_events", c.deadline_events},
                 {"flush_events", c.flush_events},
                 {"pending_at_end", c.pending_at_end},
                 {"unknown_kind", c.unknown_kind},
                 {"exposures", c.exposures},
                 {"samples", samples},
                 {"samples_withheld",
                  {{"no_camera_used", c.withheld.no_camera_used},
                   {"fewer_cameras_than_min", c.withheld.fewer_cameras_than_min}}}};
  if (compared)
    j["verify"] = {{"replayed", compared->replayed},
                   {"recorded", compared->recorded},
                   {"identical", compared->identical},
                   {"different", compared->different}};
  return j;
}

// The clearance geometry the replay runs with (clearance.geometry of its configuration):
// --clearance-geometry and the STL files it names from disk when given, else the recording's
// copies (the geometry file and meshes as the host read them, by the paths it read them at).
// Without either, or with a geometry refused: "clearance NOT replayed" and the replayed
// samples' clearance fields stay invalid (--verify shows them differing).
std::unique_ptr<clearance::SampleClearance> replay_clearance(const Recording& r,
                                                             hostapp::HostConfig cfg,
                                                             const PostOptions& p) {
  const bool from_disk = !p.clearance_geometry_path.empty();
  if (from_disk) cfg.clearance_geometry = p.clearance_geometry_path;
  if (cfg.clearance_geometry.empty()) return nullptr;
  const std::string origin =
      from_disk ? "read from " + cfg.clearance_geometry
                : "recorded in " + r.files.front() + " ('" + cfg.clearance_geometry + "')";
  if (!from_disk && !find_input(r, static_cast<int>(RecordedInputKind::kClearanceGeometry))) {
    std::fprintf(stderr,
                 "storetrack-post: clearance NOT replayed: the recording does not carry the "
                 "clearance geometry '%s' (give --clearance-geometry): the replayed samples' "
                 "clearance fields are invalid\n",
                 cfg.clearance_geometry.c_str());
    return nullptr;
  }
  const hostapp::InputReader read = [&](RecordedInputKind kind, const std::string& path) {
    if (from_disk) return jsonfile::read_text_file(path);
    const auto* recorded = find_input(r, static_cast<int>(kind), path);
    if (!recorded)
      throw InputError(r.files.front() + ": the recording does not carry the " +
                       output::to_string(kind) + " '" + path + "'");
    return std::string(recorded->bytes.begin(), recorded->bytes.end());
  };
  try {
    auto c = hostapp::load_clearance(cfg, read);
    std::fprintf(stderr, "storetrack-post: clearance: the geometry %s\n", origin.c_str());
    return c;
  } catch (const std::exception& e) {
    std::fprintf(stderr,
                 "storetrack-post: clearance NOT replayed: %s: the replayed samples' clearance "
                 "fields are invalid\n",
                 e.what());
    return nullptr;
  }
}

struct FileCloser {
  void operator()(std::FILE* f) const {
    if (f) std::fclose(f);
  }
};
using FilePtr = std::unique_ptr<std::FILE, FileCloser>;

int write_csv(output::FtiCsvWriter& csv, const std::vector<msg::FtiSample>& samples) {
  for (const msg::FtiSample& s : samples)
    if (csv.write(s) != 0) break;
  if (const int rc = csv.close(); rc != 0 || csv.rows_written() != samples.size()) {
    std::fprintf(stderr, "storetrack-post: %s: %s (%llu of %zu rows)\n", csv.path().c_str(),
                 std::strerror(rc < 0 ? -rc : EIO),
                 static_cast<unsigned long long>(csv.rows_written()), samples.size());
    return 1;
  }
  return 0;
}

// The fixed-interval smoother over a replay's samples' poses (host/smooth); `label` names the
// run in the printed counters.
std::vector<smooth::SmoothedState> smooth_replay(std::span<const smooth::PoseMeasurement> poses,
                                                 const char* label) {
  smooth::SmootherCounters counters;
  std::vector<smooth::SmoothedState> states =
      smooth::smooth_trajectory(poses, smooth::SmootherConfig{}, &counters);
  std::printf(
      "%s: %llu segment(s), %llu solved poses, %llu exposures predicted inside them, %llu "
      "outside any segment, %llu interval(s) with an acceleration step\n",
      label, static_cast<unsigned long long>(counters.segments),
      static_cast<unsigned long long>(counters.measurements),
      static_cast<unsigned long long>(counters.predicted),
      static_cast<unsigned long long>(counters.left_out),
      static_cast<unsigned long long>(counters.steps));
  return states;
}

int write_smoothed(const std::string& path, std::span<const smooth::SmoothedState> states,
                   FilePtr f) {
  if (!write_smoothed_csv(f.get(), states) || std::fclose(f.release()) != 0) {
    std::fprintf(stderr, "storetrack-post: %s: %s\n", path.c_str(), std::strerror(errno));
    return 1;
  }
  return 0;
}

// The store's CG offset from the store survey: the data product needs it. `origin` names the
// survey's file (a substitute, or the recorded one).
smooth::CgOffset required_cg(const hostapp::InputFiles& in, const hostapp::HostOptions& o,
                             const Recording& r, const PostOptions& p) {
  if (in.store.cg) return {in.store.cg->p_body, in.store.cg->sigma_m};
  const std::string origin =
      !p.store_path.empty()
          ? p.store_path
          : "the store survey recorded in " + r.files.front() + " ('" + o.store_path + "')";
  throw InputError(origin +
                   ": no \"cg\" field (the store's CG in the body frame, {\"p_body_m\": [x, "
                   "y, z], \"sigma_m\": s}, docs/post-processing.md); --product-csv needs it");
}

void print_release(const smooth::ReleaseTime& t0, time::TaiNs first_ns) {
  if (!t0.detected) {
    std::printf("release: not detected (%s): t_since_t0_s and the dcg columns are NaN\n",
                t0.reason.c_str());
    return;
  }
  std::printf(
      "release: t0 = %lld TAI ns (%.6f s after the first exposure), u(t0) = %.1f us (noise %.1f, "
      "shared %.1f); captive test alarm at %.6f s (chi-square %.1f > %.1f); onset acceleration "
      "%.2f %.2f %.2f m/s^2, fit chi-square %.1f for %d degrees of freedom\n",
      static_cast<long long>(t0.t0_ns), static_cast<double>(t0.t0_ns - first_ns) * 1e-9,
      t0.u_t0_s * 1e6, t0.u_noise_s * 1e6, t0.u_shared_s * 1e6,
      static_cast<double>(t0.alarm_ns - first_ns) * 1e-9, t0.alarm_chi2, t0.alarm_threshold,
      t0.onset_accel_p.x(), t0.onset_accel_p.y(), t0.onset_accel_p.z(), t0.fit_chi2, t0.fit_dof);
}

// The release time and the data product (host/smooth) over the smoothed states.
int write_product(const std::string& path, const Replay& replay,
                  std::span<const smooth::SmoothedState> states, const smooth::CgOffset& cg,
                  FilePtr f) {
  const smooth::ReleaseTime t0 = smooth::estimate_release_time(replay.measurements());
  print_release(t0, replay.measurements().empty() ? 0 : replay.measurements().front().t_ns);
  const std::vector<smooth::ProductSample> product =
      smooth::store_product(states, replay.measurements(), t0, cg);
  if (!write_product_csv(f.get(), product, t0) || std::fclose(f.release()) != 0) {
    std::fprintf(stderr, "storetrack-post: %s: %s\n", path.c_str(), std::strerror(errno));
    return 1;
  }
  return 0;
}

// The recording replayed again with the inputs as recorded (--differences-csv,
// --smoothed-differences-csv): its written samples' poses and, for the smoother, measurements.
struct RecordedRun {
  std::vector<RunPose> poses;
  std::vector<smooth::PoseMeasurement> measurements;
};

RecordedRun replay_recorded(const Recording& r, const hostapp::HostOptions& recorded_options,
                            const hostapp::InputFiles& recorded_inputs, bool smoothed) {
  hostapp::ProcessingChain chain =
      hostapp::make_processing_chain(recorded_options.cfg, recorded_inputs);
  chain.clearance = replay_clearance(r, recorded_options.cfg, PostOptions{});
  Replay replay(chain);
  replay.collect_measurements(smoothed);
  RecordedRun run;
  replay.on_sample([&](const pipeline::ExposureResult& e) {
    run.poses.push_back(run_pose(e, recorded_inputs.pylon.marks.size()));
  });
  for (const ch10read::RawObservation& record : r.records)
    replay.feed(record);
  replay.finish();
  run.measurements = replay.measurements();
  return run;
}

// The substituted run against the recorded inputs' (--differences-csv), paired by
// trigger_seq. Returns the summary for the stats.
nlohmann::json write_differences(const RecordedRun& recorded,
                                 const std::vector<RunPose>& substituted, const Substituted& what,
                                 const std::string& path, FilePtr f, int& exit_code) {
  const std::vector<DifferenceRow> rows = differences(recorded.poses, substituted, what);
  const DifferenceSummary summary = summarize(rows, recorded.poses, substituted);
  print_summary(stderr, summary);
  if (!write_differences_csv(f.get(), rows) || std::fclose(f.release()) != 0) {
    std::fprintf(stderr, "storetrack-post: %s: %s\n", path.c_str(), std::strerror(errno));
    exit_code = 1;
  }
  return to_json(summary);
}

// Both runs smoothed, their differences (--smoothed-differences-csv). Returns the summary.
nlohmann::json write_smoothed_differences(const RecordedRun& recorded,
                                          const std::vector<RunPose>& substituted_poses,
                                          std::span<const smooth::SmoothedState> substituted,
                                          const Substituted& what, const std::string& path,
                                          FilePtr f, int& exit_code) {
  const std::vector<smooth::SmoothedState> states =
      smooth_replay(recorded.measurements, "smoothed (inputs as recorded)");
  const SmoothedRun a{states, recorded.poses}, b{substituted, substituted_poses};
  const std::vector<SmoothedDifferenceRow> rows = smoothed_differences(a, b, what);
  const SmoothedDifferenceSummary summary = summarize(rows, a, b);
  print_summary(stderr, summary);
  if (!write_smoothed_differences_csv(f.get(), rows) || std::fclose(f.release()) != 0) {
    std::fprintf(stderr, "storetrack-post: %s: %s\n", path.c_str(), std::strerror(errno));
    exit_code = 1;
  }
  return to_json(summary);
}

// --report DIR: the replayed samples, the smoothed trajectory, the counters and (with the
// store's CG) the data product go into DIR, unless named elsewhere.
PostOptions with_report_outputs(PostOptions p, bool has_cg) {
  if (p.report_dir.empty()) return p;
  const auto in_dir = [&p](std::string& path, const char* name) {
    if (path.empty()) path = (std::filesystem::path(p.report_dir) / name).string();
  };
  in_dir(p.csv_path, "samples.csv");
  in_dir(p.smoothed_csv_path, "smoothed.csv");
  in_dir(p.stats_json_path, "stats.json");
  if (has_cg) in_dir(p.product_csv_path, "product.csv");
  return p;
}

// The report's data collected from the replay (--report).
// The calibration health test as the replay ran it (the live run's, with the recorded inputs).
void print_health(const pipeline::CalibrationHealthGuard& guard) {
  int moved = 0;
  for (const pipeline::CameraHealth& h : guard.monitor().cameras()) {
    if (!h.moved) continue;
    ++moved;
    std::printf(
        "calibration health: camera %d declared moved after %llu exposures of the replay "
        "(%llu alarms in %llu windows)\n",
        h.camera_id, static_cast<unsigned long long>(h.first_alarm_exposure),
        static_cast<unsigned long long>(h.alarms),
        static_cast<unsigned long long>(h.windows_tested));
  }
  if (moved == 0)
    std::printf("calibration health: no camera declared moved (%llu exposures tested)\n",
                static_cast<unsigned long long>(guard.monitor().exposures()));
}

// --clearance-csv: its rows written and closed, else the failure named; 0 or -1.
int close_clearance_csv(hostapp::CsvFile& f) {
  const std::uint64_t write_errors = f.write_errors();
  const int rc = f.close();
  if (write_errors == 0 && rc == 0) return 0;
  std::fprintf(stderr, "storetrack-post: %s: %llu write error(s)%s%s\n", f.path().c_str(),
               static_cast<unsigned long long>(write_errors), rc != 0 ? ", close: " : "",
               rc != 0 ? std::strerror(-rc) : "");
  return -1;
}

// --output-ch10: refused by name when it exists (nothing is written).
void open_new_recording(ReprocessedRecording& out, const std::string& path,
                        const output::Chapter10Config& config) {
  if (const int rc = out.open(path, config); rc != 0)
    throw InputError(path + ": " +
                     (rc == -EEXIST ? std::string("exists; storetrack-post writes new files only")
                                    : std::string(std::strerror(-rc))));
}

int close_new_recording(ReprocessedRecording& out) {
  const int rc = out.close();
  const output::Chapter10Counters& c = out.writer().counters();
  std::string files;
  for (const std::string& f : out.writer().files())
    files += (files.empty() ? "" : ", ") + f;
  std::printf(
      "new recording: %s: %llu samples, %llu raw records, %llu input packets, %llu packets, "
      "%llu bytes; %llu samples and %llu raw records in no file\n",
      files.c_str(), static_cast<unsigned long long>(c.messages_written),
      static_cast<unsigned long long>(c.raw_messages_written),
      static_cast<unsigned long long>(c.input_packets),
      static_cast<unsigned long long>(c.packets_written),
      static_cast<unsigned long long>(c.bytes_written),
      static_cast<unsigned long long>(c.messages_dropped),
      static_cast<unsigned long long>(c.raw_messages_dropped + c.raw_refused));
  if (rc == 0) return 0;
  std::fprintf(stderr, "storetrack-post: %s: %s\n", files.c_str(), std::strerror(-rc));
  return 1;
}

struct ReportRows {
  std::vector<CameraResidualRow> residuals;
  std::vector<ExposureRow> exposures;
  std::vector<CalibrationResidual> calibration;
  HealthHistory health;  ///< calibration_health.csv (when the recorded run had the test on)
};

int write_report(const PostOptions& p, const Recording& r, const Replay& replay,
                 const ReportRows& rows) {
  // Absolute: the renderer may run from another directory.
  const auto where = [](const std::string& path) {
    std::error_code ec;
    return path.empty() ? path : std::filesystem::absolute(path, ec).string();
  };
  const nlohmann::json files = {{"samples", where(p.csv_path)},
                                {"smoothed", where(p.smoothed_csv_path)},
                                {"product", where(p.product_csv_path)},
                                {"stats", where(p.stats_json_path)}};
  const bool health_ok = rows.health.rows().empty() || [&] {
    const FilePtr f(
        create_output((std::filesystem::path(p.report_dir) / "calibration_health.csv").string()));
    return write_health_csv(f.get(), rows.health.rows()) && std::fflush(f.get()) == 0;
  }();
  if (health_ok && write_report_tables(p.report_dir, r, replay.counters(), rows.residuals,
                                       rows.exposures, rows.calibration, files))
    return 0;
  std::fprintf(stderr, "storetrack-post: %s: %s\n", p.report_dir.c_str(), std::strerror(errno));
  return 1;
}

int run(const PostOptions& given) {
  const Recording r = read_recording(given.recording_files);
  for (const std::string& torn : r.torn)
    std::fprintf(stderr, "storetrack-post: %s: replaying up to its last whole packet\n",
                 torn.c_str());
  for (const std::string& gap : r.gaps)
    std::fprintf(stderr, "storetrack-post: %s\n", gap.c_str());
  hostapp::HostOptions o = recorded_host_options(r, given);
  hostapp::InputFiles in;
  UsedInputs used_inputs;  // the bytes the replay runs with, for --output-ch10
  hostapp::load_inputs(o, used_inputs.recording(make_input_reader(r, given)), in);
  const PostOptions p = with_report_outputs(given, in.store.cg.has_value());
  // The inputs as recorded: a substitute is checked against them, and compared with.
  const Substituted what{!p.calibration_path.empty(), !p.pylon_path.empty(), !p.store_path.empty(),
                         !p.config_path.empty()};
  PostOptions as_recorded;
  as_recorded.recording_files = p.recording_files;
  hostapp::HostOptions o_recorded = recorded_host_options(r, as_recorded);
  hostapp::InputFiles in_recorded;
  if (what.any()) hostapp::load_inputs(o_recorded, make_input_reader(r, as_recorded), in_recorded);
  if (what.calibration)
    check_same_rig(in_recorded.rig, r.files.front(), in.rig, p.calibration_path);
  for (const auto& [path, option] :
       {std::pair{&p.differences_csv_path, "--differences-csv"},
        std::pair{&p.smoothed_differences_csv_path, "--smoothed-differences-csv"}})
    if (!path->empty() && !what.any())
      throw InputError(*path + ": " + option +
                       " compares with a substituted input: give --calibration, --pylon-survey, "
                       "--store-survey or --config");
  hostapp::ProcessingChain chain = hostapp::make_processing_chain(o.cfg, in);
  chain.clearance = replay_clearance(r, o.cfg, p);
  if (!p.clearance_csv_path.empty() && !chain.clearance)
    throw InputError(p.clearance_csv_path +
                     ": --clearance-csv needs the clearance geometry: the recording's "
                     "configuration names none that it carries (give --clearance-geometry)");
  smooth::CgOffset cg;
  if (!p.product_csv_path.empty()) cg = required_cg(in, o, r, p);

  // Outputs are created before the replay: a refused name costs no replay. All are checked
  // first, so one refused name leaves no other output behind.
  if (!p.report_dir.empty()) prepare_report_dir(p.report_dir);
  for (const std::string* out :
       {&p.csv_path, &p.stats_json_path, &p.smoothed_csv_path, &p.product_csv_path,
        &p.differences_csv_path, &p.smoothed_differences_csv_path, &p.output_ch10_path,
        &p.clearance_csv_path})
    if (std::error_code ec; !out->empty() && std::filesystem::exists(*out, ec))
      throw InputError(*out + ": exists; storetrack-post writes new files only");
  output::FtiCsvWriter csv;
  if (!p.csv_path.empty()) {
    if (const int rc = csv.open(p.csv_path, false); rc != 0)
      throw InputError(p.csv_path + ": " +
                       (rc == -EEXIST ? std::string("exists; storetrack-post writes new files only")
                                      : std::string(std::strerror(-rc))));
  }
  FilePtr stats(p.stats_json_path.empty() ? nullptr : create_output(p.stats_json_path));
  FilePtr smoothed(p.smoothed_csv_path.empty() ? nullptr : create_output(p.smoothed_csv_path));
  FilePtr product(p.product_csv_path.empty() ? nullptr : create_output(p.product_csv_path));
  FilePtr diffs(p.differences_csv_path.empty() ? nullptr : create_output(p.differences_csv_path));
  FilePtr smoothed_diffs(p.smoothed_differences_csv_path.empty()
                             ? nullptr
                             : create_output(p.smoothed_differences_csv_path));
  hostapp::CsvFile clearance_csv;
  if (!p.clearance_csv_path.empty())
    if (const int rc =
            clearance_csv.open(p.clearance_csv_path, hostapp::kClearanceCsvHeader, false);
        rc != 0)
      throw InputError(p.clearance_csv_path + ": " + std::strerror(-rc));
  ReprocessedRecording new_recording;
  if (!p.output_ch10_path.empty())
    open_new_recording(new_recording, p.output_ch10_path,
                       reprocessed_config(r, o, in, used_inputs, what));

  Replay replay(chain);
  if (clearance_csv.is_open()) replay.write_clearance_rows(&clearance_csv);
  replay.collect_measurements(smoothed || product || smoothed_diffs);
  std::vector<RunPose> substituted_poses;
  if (diffs || smoothed_diffs)
    replay.on_sample([&](const pipeline::ExposureResult& e) {
      substituted_poses.push_back(run_pose(e, in.pylon.marks.size()));
    });
  ReportRows report;
  ResidualDiagnostics diagnostics(in.rig, chain.processor->factors());
  if (!p.report_dir.empty())
    replay.on_exposure([&report, &diagnostics, &chain](const pipeline::AlignedExposure& e,
                                                       const pipeline::ExposureResult& result,
                                                       bool written, bool processor_rebuilt) {
      for (const CameraResidualRow& row : diagnostics.add(e, result))
        report.residuals.push_back(row);
      if (processor_rebuilt)
        diagnostics.use_calibration(chain.processor->rig(), chain.processor->factors());
      report.exposures.push_back(exposure_row(e, result, written));
      if (chain.health)
        report.health.observe(*chain.health, e.trigger_seq, result.reference_mid_tai_ns);
    });
  for (const ch10read::RawObservation& record : r.records) {
    new_recording.copy(record);  // as live: the message recorded before what it completes
    replay.feed(record);
    new_recording.record_new(replay.samples());
  }
  replay.finish();
  if (!p.report_dir.empty()) report.calibration = diagnostics.calibration_residuals();
  print_summary(r, replay.counters(), replay.samples().size());
  if (chain.health) print_health(*chain.health);

  int exit_code = 0;
  SampleComparison compared;
  if (p.verify) {
    compared = compare_samples(replay.samples(), r.samples);
    const bool ended_early = !r.torn.empty() || replay.counters().flush_events == 0;
    if (!report_comparison(compared, ended_early)) exit_code = 1;
  }
  if (!p.csv_path.empty() && write_csv(csv, replay.samples()) != 0) exit_code = 1;
  if (!p.output_ch10_path.empty() && close_new_recording(new_recording) != 0) exit_code = 1;
  if (clearance_csv.is_open() && close_clearance_csv(clearance_csv) != 0) exit_code = 1;
  std::vector<smooth::SmoothedState> states;
  if (smoothed || product || smoothed_diffs) {
    states = smooth_replay(replay.measurements(), "smoothed");
    if (smoothed && write_smoothed(p.smoothed_csv_path, states, std::move(smoothed)) != 0)
      exit_code = 1;
    if (product && write_product(p.product_csv_path, replay, states, cg, std::move(product)) != 0)
      exit_code = 1;
  }
  nlohmann::json differences_json, smoothed_differences_json;
  if (diffs || smoothed_diffs) {
    const RecordedRun recorded =
        replay_recorded(r, o_recorded, in_recorded, static_cast<bool>(smoothed_diffs));
    if (diffs)
      differences_json = write_differences(recorded, substituted_poses, what,
                                           p.differences_csv_path, std::move(diffs), exit_code);
    if (smoothed_diffs)
      smoothed_differences_json = write_smoothed_differences(recorded, substituted_poses, states,
                                                             what, p.smoothed_differences_csv_path,
                                                             std::move(smoothed_diffs), exit_code);
  }
  if (!p.report_dir.empty() && write_report(p, r, replay, report) != 0) exit_code = 1;
  if (stats) {
    nlohmann::json j =
        stats_json(r, replay.counters(), replay.samples().size(), p.verify ? &compared : nullptr);
    if (!differences_json.is_null()) j["differences"] = differences_json;
    if (!smoothed_differences_json.is_null()) j["smoothed_differences"] = smoothed_differences_json;
    if (chain.health) j["calibration_health"] = hostapp::calibration_health_json(*chain.health);
    if (!p.clearance_csv_path.empty())
      j["clearance_csv"] = {{"file", p.clearance_csv_path},
                            {"bytes", clearance_csv.bytes_written()},
                            {"write_errors", clearance_csv.write_errors()}};
    if (!p.output_ch10_path.empty()) {
      const output::Chapter10Counters& c = new_recording.writer().counters();
      j["output_ch10"] = {{"files", new_recording.writer().files()},
                          {"samples", c.messages_written},
                          {"raw_records", c.raw_messages_written},
                          {"packets", c.packets_written},
                          {"bytes", c.bytes_written},
                          {"samples_in_no_file", c.messages_dropped},
                          {"raw_records_in_no_file", c.raw_messages_dropped + c.raw_refused}};
    }
    const std::string text = j.dump(2) + "\n";
    if (std::fwrite(text.data(), 1, text.size(), stats.get()) != text.size() ||
        std::fclose(stats.release()) != 0) {
      std::fprintf(stderr, "storetrack-post: %s: %s\n", p.stats_json_path.c_str(),
                   std::strerror(errno));
      exit_code = 1;
    }
  }
  return exit_code;
}

}  // namespace

int run_post(const PostOptions& o) {
  spdlog::set_level(spdlog::level::from_str(o.log_level));
  try {
    return run(o);
  } catch (const std::exception& e) {
    // Unreadable or refused recordings, inputs and configurations: each names its file.
    std::fprintf(stderr, "storetrack-post: %s\n", e.what());
    return 2;
  }
}

}  // namespace storetrack::post
