#include "diagnostic_csv.hpp"

#include <algorithm>
#include <cerrno>
#include <cinttypes>
#include <cmath>

#include <cstdarg>
#include "storetrack/output/csv_writer.hpp"

namespace storetrack::hostapp {

const char* const kMarksCsvHeader =
    "trigger_seq [1],reference_mid_tai_ns [ns],mark_id [1],body [p|s|?],"
    "excluded [0|1],x_w [m],y_w [m],z_w [m],u_x_w [m],u_y_w [m],u_z_w [m],"
    "camera_id [1],u_obs [px],v_obs [px],residual_u [px],residual_v [px],"
    "sigma [px],cov_xy_w [m^2],cov_xz_w [m^2],cov_yz_w [m^2]";
const char* const kRigidCsvHeader =
    "trigger_seq [1],body [p|s],id_a [1],id_b [1],distance [m],surveyed [m],"
    "sigma [m],z2 [1]";
// Frame p: the pylon's. The clearance values at 17 digits (the FTI fields are their float32).
const char* const kClearanceCsvHeader =
    "trigger_seq [1],exposure_mid_tai_ns [ns],part [name],store_part [name],clearance_m [m],"
    "u_clearance_m [m],clearance_lower_bound_m [m],penetration [0|1],feature [name],"
    "p_store_x_p [m],p_store_y_p [m],p_store_z_p [m],p_aircraft_x_p [m],p_aircraft_y_p [m],"
    "p_aircraft_z_p [m],normal_x_p [1],normal_y_p [1],normal_z_p [1],alarm [0|1],"
    "extrapolated [0|1]";

namespace {

__attribute__((format(printf, 2, 3))) void append_format(std::string& out, const char* format,
                                                         ...) {
  char line[1024];  // a clearance row with long part names
  va_list args;
  va_start(args, format);
  const int n = std::vsnprintf(line, sizeof line, format, args);
  va_end(args);
  if (n > 0) out.append(line, std::min(static_cast<std::size_t>(n), sizeof line - 1));
}

}  // namespace

void format_marks_rows(const pipeline::AlignedExposure& e, const pipeline::ExposureResult& r,
                       std::string& out) {
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
      append_format(
          out,
          "%" PRIu32 ",%" PRId64
          ",%d,%c,%d,%.9g,%.9g,%.9g,%.4g,%.4g,%.4g,%d,%.3f,%.3f,%.5f,%.5f,%.4f,%.4g,%.4g,%.4g\n",
          e.trigger_seq, r.reference_mid_tai_ns, m.id, m.body, m.excluded ? 1 : 0, m.p_w.x(),
          m.p_w.y(), m.p_w.z(), su, sv, sw, o.camera_id, u, v, o.residual_px.x(), o.residual_px.y(),
          o.sigma_px, m.cov_w(0, 1), m.cov_w(0, 2), m.cov_w(1, 2));
    }
  }
}

void format_rigid_rows(std::uint32_t trigger_seq, char body, const rigid::RigidCheckResult& c,
                       std::string& out) {
  for (const auto& p : c.pairs) {
    append_format(out, "%" PRIu32 ",%c,%d,%d,%.9g,%.9g,%.4g,%.4g\n", trigger_seq, body, p.id_a,
                  p.id_b, p.distance_m, p.surveyed_m, p.sigma_m, p.z2);
  }
}

void format_clearance_rows(const msg::FtiSample& s, bool extrapolated,
                           const clearance::SampleClearance& c, std::string& out) {
  for (const clearance::PartClearance& p : c.parts()) {
    // As SampleClearance::apply: a bound that is not a number cannot clear the threshold.
    const bool alarm = !(p.lower_bound_m >= c.alarm_threshold_m());
    append_format(out,
                  "%" PRIu32 ",%" PRId64
                  ",%.*s,%.*s,%.17g,%.17g,%.17g,%d,%s,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,"
                  "%.9g,%d,%d\n",
                  s.trigger_seq, s.exposure_mid_tai_ns, static_cast<int>(p.part.size()),
                  p.part.data(), static_cast<int>(p.store_part.size()), p.store_part.data(),
                  p.distance_m, p.u_distance_m, p.lower_bound_m, p.penetration ? 1 : 0,
                  clearance::feature_name(p.feature), p.p_store_p.x(), p.p_store_p.y(),
                  p.p_store_p.z(), p.p_aircraft_p.x(), p.p_aircraft_p.y(), p.p_aircraft_p.z(),
                  p.normal_p.x(), p.normal_p.y(), p.normal_p.z(), alarm ? 1 : 0,
                  extrapolated ? 1 : 0);
  }
}

CsvFile::~CsvFile() {
  close();
}

int CsvFile::open(const std::string& path, const char* header, bool number_if_exists) {
  close();
  file_ = output::fopen_new_file(path, number_if_exists, path_);
  if (!file_) return -errno;
  const std::string line = std::string(header) + "\n";
  return write(line);
}

int CsvFile::write(const std::string& rows) {
  if (!file_) return -EBADF;
  if (std::fwrite(rows.data(), 1, rows.size(), file_) != rows.size()) {
    ++errors_;
    const int rc = errno ? -errno : -EIO;
    std::clearerr(file_);
    return rc;
  }
  bytes_ += rows.size();
  return 0;
}

int CsvFile::close() {
  if (!file_) return 0;
  // fclose flushes the buffer: a full disk shows here.
  const int rc = std::fclose(file_) == 0 ? 0 : -errno;
  file_ = nullptr;
  return rc;  // counted by the caller as a close error, apart from the write errors
}

}  // namespace storetrack::hostapp
