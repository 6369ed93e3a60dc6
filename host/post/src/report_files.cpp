#include "report_files.hpp"

#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <memory>
#include <set>
#include <stdexcept>

#include "storetrack/output/csv_writer.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::post {

namespace {

namespace fs = std::filesystem;

struct FileCloser {
  void operator()(std::FILE* f) const {
    if (f) std::fclose(f);
  }
};
using FilePtr = std::unique_ptr<std::FILE, FileCloser>;

FilePtr create(const std::string& dir, const char* name) {
  std::string created;
  return FilePtr(output::fopen_new_file((fs::path(dir) / name).string(), false, created));
}

bool finish(FilePtr f) {
  return f && !std::ferror(f.get()) && std::fclose(f.release()) == 0;
}

bool write_residuals(const std::string& dir, std::span<const CameraResidualRow> rows) {
  FilePtr f = create(dir, "residuals.csv");
  if (!f) return false;
  std::fprintf(f.get(),
               "trigger_seq,t_tai_ns [ns],camera_id,delivered,marks_reported,residuals,differences,"
               "noise_chi2,noise_dof\n");
  for (const CameraResidualRow& r : rows)
    std::fprintf(f.get(), "%u,%lld,%d,%d,%d,%d,%d,%.9g,%.9g\n", r.trigger_seq,
                 static_cast<long long>(r.t_tai_ns), r.camera_id, r.delivered ? 1 : 0,
                 r.marks_reported, r.residuals, r.differences, r.noise_chi2, r.noise_dof);
  return finish(std::move(f));
}

bool write_windows(const std::string& dir, std::span<const ResidualWindow> windows) {
  FilePtr f = create(dir, "residual_windows.csv");
  if (!f) return false;
  std::fprintf(f.get(),
               "camera_id,first_seq,last_seq,first_t_tai_ns [ns],last_t_tai_ns [ns],exposures,"
               "differences,chi2,dof,rms_normalised,band_low,band_high,inside\n");
  for (const ResidualWindow& w : windows)
    std::fprintf(f.get(), "%d,%u,%u,%lld,%lld,%d,%d,%.9g,%.9g,%.6f,%.6f,%.6f,%d\n", w.camera_id,
                 w.first_seq, w.last_seq, static_cast<long long>(w.first_t_tai_ns),
                 static_cast<long long>(w.last_t_tai_ns), w.exposures, w.residuals, w.chi2, w.dof,
                 w.rms_normalised, w.band_low, w.band_high, w.inside() ? 1 : 0);
  return finish(std::move(f));
}

// The 0.99 quantile of a pose fit's chi-square over n marks (NaN without a fit).
double fit_quantile(int marks) {
  if (marks < 3) return std::nan("");
  return uncertainty::chi_square_quantile(uncertainty::Probability(0.99),
                                          uncertainty::DegreesOfFreedom(3 * marks - 6));
}

bool write_exposures(const std::string& dir, std::span<const ExposureRow> rows) {
  FilePtr f = create(dir, "exposures.csv");
  if (!f) return false;
  std::fprintf(f.get(),
               "trigger_seq,t_tai_ns [ns],written,cameras_delivered,missing_camera_mask,"
               "closed_by_timeout,store_marks,store_chi2,store_chi2_q99,pylon_marks,pylon_chi2,"
               "pylon_chi2_q99\n");
  for (const ExposureRow& r : rows)
    std::fprintf(f.get(), "%u,%lld,%d,%d,%u,%d,%d,%.9g,%.9g,%d,%.9g,%.9g\n", r.trigger_seq,
                 static_cast<long long>(r.t_tai_ns), r.written ? 1 : 0, r.cameras_delivered,
                 r.missing_camera_mask, r.closed_by_timeout ? 1 : 0, r.store_marks, r.store_chi2,
                 fit_quantile(r.store_marks), r.pylon_marks, r.pylon_chi2,
                 fit_quantile(r.pylon_marks));
  return finish(std::move(f));
}

nlohmann::json exceedance_json(const ChiSquareExceedance& x) {
  return {{"fits", x.fits},
          {"above_quantile", x.above},
          {"quantile", x.probability},
          {"band_low", x.band_low},
          {"band_high", x.band_high},
          {"inside", x.fits == 0 || (x.above >= x.band_low && x.above <= x.band_high)}};
}

nlohmann::json windows_json(std::span<const ResidualWindow> windows) {
  nlohmann::json per_camera = nlohmann::json::object();
  for (const ResidualWindow& w : windows) {
    nlohmann::json& c = per_camera[std::to_string(w.camera_id)];
    if (c.is_null()) c = {{"windows", 0}, {"inside", 0}};
    c["windows"] = c["windows"].get<int>() + 1;
    c["inside"] = c["inside"].get<int>() + (w.inside() ? 1 : 0);
  }
  const WindowsInside all = windows_inside(windows);
  return {{"window_exposures", kResidualWindowExposures},
          {"band_probability", kResidualBandProbability},
          {"windows", all.windows},
          {"inside", all.inside},
          {"inside_band_low", all.band_low},
          {"inside_band_high", all.band_high},
          {"acceptable", all.windows == 0 || all.acceptable()},
          {"per_camera", per_camera}};
}

// The shared (calibration) part: one chi-square per camera against its own band, and the
// cameras outside it named (above: the calibration is off by more than stated; below: its
// stated uncertainty is larger than the residuals show).
nlohmann::json calibration_json(std::span<const CalibrationResidual> cameras) {
  nlohmann::json per_camera = nlohmann::json::array(), above = nlohmann::json::array(),
                 below = nlohmann::json::array();
  for (const CalibrationResidual& c : cameras) {
    per_camera.push_back({{"camera_id", c.camera_id},
                          {"span", c.span},
                          {"first_trigger_seq", c.first_trigger_seq},
                          {"last_trigger_seq", c.last_trigger_seq},
                          {"marks", c.marks},
                          {"views", c.views},
                          {"chi2", c.chi2},
                          {"dof", c.dof},
                          {"band_low", c.band_low},
                          {"band_high", c.band_high},
                          {"calibration_share", c.calibration_share},
                          {"inside", c.inside()}});
    if (c.chi2 > c.band_high) above.push_back(c.camera_id);
    if (c.chi2 < c.band_low) below.push_back(c.camera_id);
  }
  return {{"band_probability", calibration_band_probability(static_cast<int>(cameras.size()))},
          {"family_probability", kResidualBandProbability},
          {"per_camera", per_camera},
          {"cameras_above", above},
          {"cameras_below", below}};
}

}  // namespace

void prepare_report_dir(const std::string& dir) {
  std::error_code ec;
  if (fs::exists(dir, ec)) {
    if (!fs::is_directory(dir, ec))
      throw std::runtime_error(dir +
                               ": exists and is not a directory; --report writes a new "
                               "(or empty) directory");
    if (!fs::is_empty(dir, ec))
      throw std::runtime_error(dir +
                               ": not empty; storetrack-post writes new files only (give "
                               "a new or empty directory)");
    return;
  }
  if (!fs::create_directories(dir, ec))
    throw std::runtime_error(dir + ": cannot create the directory: " + ec.message());
}

nlohmann::json integrity_json(const Recording& r, const ReplayCounters& c,
                              std::span<const ExposureRow> exposures) {
  nlohmann::json files = nlohmann::json::array();
  for (const FileIntegrity& f : r.integrity)
    files.push_back({{"file", f.file},
                     {"file_bytes", f.file_bytes},
                     {"bytes_in_whole_packets", f.bytes_in_whole_packets},
                     {"packets", f.packets},
                     {"header_checksum_errors", f.header_checksum_errors},
                     {"data_checksum_errors", f.data_checksum_errors},
                     {"sequence_gap_packets", f.sequence_gap_packets},
                     {"raw_data_errors", f.raw_data_errors},
                     {"raw_format_errors", f.raw_format_errors},
                     {"torn", f.torn},
                     {"stop_reason", f.stop_reason}});
  // Exposures the aligner never released: trigger numbers skipped between the first and last.
  std::set<std::uint32_t> seqs;
  for (const ExposureRow& e : exposures)
    seqs.insert(e.trigger_seq);
  const std::uint64_t span = seqs.empty() ? 0 : *seqs.rbegin() - *seqs.begin() + 1;
  return {{"files", files},
          {"continuation_files", r.files.empty() ? 0 : r.files.size() - 1},
          {"torn", r.torn},
          {"gaps_between_files", r.gaps},
          {"raw_records", c.records},
          {"refused_live", c.refused_live},
          {"undecodable", c.undecodable},
          {"exposures_processed", seqs.size()},
          {"exposures_missing", span - seqs.size()},
          {"samples_recorded", r.samples.size()},
          {"host_ended_normally", c.flush_events > 0}};
}

bool write_report_tables(const std::string& dir, const Recording& r, const ReplayCounters& c,
                         std::span<const CameraResidualRow> residuals,
                         std::span<const ExposureRow> exposures,
                         std::span<const CalibrationResidual> calibration,
                         const nlohmann::json& files) {
  const std::vector<ResidualWindow> windows = residual_windows(residuals, kResidualWindowExposures);
  if (!write_residuals(dir, residuals) || !write_windows(dir, windows) ||
      !write_exposures(dir, exposures))
    return false;
  const nlohmann::json j = {{"files", files},
                            {"integrity", integrity_json(r, c, exposures)},
                            {"residual_windows", windows_json(windows)},
                            {"calibration_residuals", calibration_json(calibration)},
                            {"rigid_store", exceedance_json(rigid_exceedance(exposures, true))},
                            {"rigid_pylon", exceedance_json(rigid_exceedance(exposures, false))}};
  FilePtr f = create(dir, "report.json");
  if (!f) return false;
  const std::string text = j.dump(2) + "\n";
  return std::fwrite(text.data(), 1, text.size(), f.get()) == text.size() && finish(std::move(f));
}

}  // namespace storetrack::post
