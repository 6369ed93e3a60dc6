#include "host_setup.hpp"

#include <spdlog/spdlog.h>
#include <stdexcept>
#include <vector>

#include "storetrack/match/mark_matcher.hpp"

namespace storetrack::hostapp {

using output::RecordedInputKind;

void load_inputs(HostOptions& o, const InputReader& read, InputFiles& in) {
  HostConfig& cfg = o.cfg;
  if (!o.config_path.empty())
    parse_host_config(read(RecordedInputKind::kHostConfig, o.config_path), o.config_path, cfg);
  in.rig = camera::parse_rig_calibration(read(RecordedInputKind::kCalibration, o.calibration_path),
                                         o.calibration_path);
  in.pylon =
      survey::parse_survey(read(RecordedInputKind::kPylonSurvey, o.pylon_path), o.pylon_path);
  in.store =
      survey::parse_survey(read(RecordedInputKind::kStoreSurvey, o.store_path), o.store_path);
  if (!o.initial_marks_path.empty())
    cfg.initial_marks_w = parse_initial_marks(
        read(RecordedInputKind::kInitialMarks, o.initial_marks_path), o.initial_marks_path);
  if (in.rig.cameras.empty() || in.rig.cameras.size() > 32)
    throw std::runtime_error(o.calibration_path + ": the rig needs 1..32 cameras (has " +
                             std::to_string(in.rig.cameras.size()) + ")");
  if (o.max_wait_ms > 0) set_max_wait_ms(cfg, o.max_wait_ms, "--max-wait-ms");
  if (o.min_cameras > 0) cfg.aligner.min_cameras = o.min_cameras;
  for (const auto& text : o.udp_sources)
    cfg.udp_sources.push_back(parse_udp_source(text));
  if (o.no_udp_kernel_filter) cfg.udp_kernel_filter = false;
  std::vector<int> camera_ids, unit_ids;
  for (const auto& c : in.rig.cameras) {
    camera_ids.push_back(c.camera_id);
    unit_ids.push_back(c.unit_id);
  }
  finish_host_config(cfg, camera_ids, unit_ids);
}

namespace {

// Mark identification: the processor's MarkMatcher. Its prior poses (acquisition, and
// re-acquisition of a body lost for longer than its track gap) are fitted to the installation
// survey's initial mark positions; without them it cannot acquire a body.
void set_prior_poses(const HostConfig& cfg, const InputFiles& in,
                     pipeline::ExposureProcessor& processor) {
  std::vector<geometry::Transform> fitted;
  for (const auto* body : {&in.pylon, &in.store}) {
    geometry::Transform T_w_b;
    geometry::Mat6 cov;
    if (match::fit_body_pose(*body, cfg.initial_marks_w, cfg.initial_marks_sigma_m, T_w_b, cov)) {
      processor.matcher().set_prior_pose(body->name, T_w_b, cov);
      fitted.push_back(T_w_b);
    } else {
      spdlog::warn(
          "no prior pose for '{}' (needs >= 3 non-collinear of its marks in --initial-marks): "
          "its marks cannot be identified",
          body->name);
    }
  }
  // The store's region relative to the pylon (re-acquisition), around its installation pose.
  if (cfg.store_region.valid && fitted.size() == 2) {
    match::BodyRegion region;
    region.reference_body = in.pylon.name;
    region.T_ref_b_nominal = fitted[0].inverse() * fitted[1];
    region.max_rotation_rad = cfg.store_region.max_rotation_rad;
    region.min_offset_m = cfg.store_region.min_offset_m;
    region.max_offset_m = cfg.store_region.max_offset_m;
    processor.matcher().set_region(in.store.name, region);
  }
}

std::unique_ptr<pipeline::ExposureProcessor> make_processor(const HostConfig& cfg,
                                                            const InputFiles& in,
                                                            const camera::RigCalibration& rig) {
  pipeline::ProcessorConfig pc = cfg.processor;
  pc.rigid_pair_statistics = !cfg.rigid_csv_path.empty();  // they feed only that CSV
  auto processor = std::make_unique<pipeline::ExposureProcessor>(rig, in.pylon, in.store, pc);
  set_prior_poses(cfg, in, *processor);
  return processor;
}

}  // namespace

ProcessingChain make_processing_chain(const HostConfig& cfg, const InputFiles& in) {
  ProcessingChain chain;
  chain.cfg = cfg;
  chain.in = in;
  chain.processor = make_processor(cfg, in, in.rig);
  chain.aligner = std::make_unique<ingest::ExposureAligner>(cfg.aligner);
  if (cfg.calibration_health_enabled)
    chain.health = std::make_unique<pipeline::CalibrationHealthGuard>(
        in.rig, in.pylon, cfg.calibration_health, cfg.calibration_health_mode);
  return chain;
}

std::unique_ptr<clearance::SampleClearance> load_clearance(
    const HostConfig& cfg, const InputReader& read,
    std::vector<output::RecordedInputFile>* read_files) {
  if (cfg.clearance_geometry.empty()) return nullptr;
  bool geometry_read = false;  // the first file read is the geometry file, the rest its meshes
  const clearance::GeometryFileReader read_file = [&](const std::string& path) {
    const RecordedInputKind kind =
        geometry_read ? RecordedInputKind::kClearanceMesh : RecordedInputKind::kClearanceGeometry;
    geometry_read = true;
    std::string bytes = read(kind, path);
    if (read_files) read_files->push_back({kind, path, {bytes.begin(), bytes.end()}});
    return bytes;
  };
  return std::make_unique<clearance::SampleClearance>(
      clearance::ClearanceModel::load(cfg.clearance_geometry, read_file),
      cfg.clearance_alarm_threshold_m);
}

ProcessedExposure process_exposure(ProcessingChain& chain, const pipeline::AlignedExposure& e) {
  ProcessedExposure out{chain.health ? &chain.health->filter(e) : &e, chain.result};
  chain.processor->process(*out.exposure, out.result);
  if (chain.health && chain.health->observe(*out.exposure, out.result)) {
    // The same chain on the corrected rig: its matcher's priors fitted again, its tracks new.
    chain.processor = make_processor(chain.cfg, chain.in, chain.health->rig());
    out.processor_rebuilt = true;
  }
  if (chain.clearance) {
    pipeline::ExposureResult& r = out.result;
    if (r.T_p_s.valid)
      chain.clearance->apply(r.T_p_s.T, r.T_p_s.cov, r.sample);
    else if (r.extrapolated)
      chain.clearance->apply(r.T_p_s_extrapolated, r.cov_T_p_s_extrapolated, r.sample);
    out.clearance_evaluated = r.T_p_s.valid || r.extrapolated;
    out.clearance_extrapolated = !r.T_p_s.valid && r.extrapolated;
  }
  return out;
}

}  // namespace storetrack::hostapp
