#include "storetrack/output/csv_writer.hpp"

#include <sys/stat.h>

#include <cerrno>
#include <cinttypes>
#include <span>

#include "storetrack/output/chapter10_writer.hpp"

namespace storetrack::output {

std::vector<std::string> fti_csv_columns() {
  std::vector<std::string> c = {"trigger_seq [1]",
                                "exposure_mid_tai_ns [ns]",
                                "store_id [1]",
                                "status [bitfield]",
                                "cameras_used [1]",
                                "marks_used [1]",
                                "pylon_marks_used [1]",
                                "x [m]",
                                "y [m]",
                                "z [m]",
                                "yaw [rad]",
                                "pitch [rad]",
                                "roll [rad]",
                                "u_x [m]",
                                "u_y [m]",
                                "u_z [m]",
                                "u_yaw [rad]",
                                "u_pitch [rad]",
                                "u_roll [rad]"};
  const char* names[6] = {"x", "y", "z", "yaw", "pitch", "roll"};
  for (int i = 0; i < 6; ++i)
    for (int j = i + 1; j < 6; ++j)
      c.push_back(std::string("r_") + names[i] + "_" + names[j] + " [1]");
  for (const char* b : {"u_budget_centroid [m]", "u_budget_intrinsic [m]", "u_budget_extrinsic [m]",
                        "u_budget_sync [m]", "u_budget_process [m]", "coverage_factor [1]",
                        "clearance [m]", "u_clearance [m]", "clearance_lower_bound [m]"})
    c.emplace_back(b);
  c.emplace_back("clearance_part [1]");
  return c;
}

std::FILE* fopen_new_file(const std::string& path, bool number_if_exists, std::string& created) {
  for (int number = 0; number <= kMaxChapter10FileNumber; ++number) {
    created = number == 0 ? path : numbered_chapter10_path(path, number);
    if (std::FILE* f = std::fopen(created.c_str(), "wx")) return f;  // "x": O_EXCL
    if (errno != EEXIST) return nullptr;
    // A FIFO or device (a live display, /dev/stdout) holds no recording to overwrite.
    struct stat st {};
    if (number == 0 && ::stat(path.c_str(), &st) == 0 && !S_ISREG(st.st_mode))
      return std::fopen(path.c_str(), "w");
    if (!number_if_exists) return nullptr;
  }
  errno = EEXIST;
  return nullptr;
}

FtiCsvWriter::~FtiCsvWriter() {
  close();
}

int FtiCsvWriter::open(const std::string& path, bool number_if_exists) {
  close();
  file_ = fopen_new_file(path, number_if_exists, path_);
  if (!file_) return -errno;
  // Line-buffered: a reader (progress display, crash) sees every complete row.
  std::setvbuf(file_, nullptr, _IOLBF, 0);
  const auto columns = fti_csv_columns();
  for (std::size_t i = 0; i < columns.size(); ++i)
    std::fprintf(file_, "%s%s", i ? "," : "", columns[i].c_str());
  std::fputc('\n', file_);
  rows_ = 0;
  return 0;
}

int FtiCsvWriter::write(const msg::FtiSample& s) {
  if (!file_) return -EBADF;
  std::fprintf(file_, "%" PRIu32 ",%" PRId64 ",%u,%u,%u,%u,%u", s.trigger_seq,
               s.exposure_mid_tai_ns, unsigned{s.store_id}, unsigned{s.status},
               unsigned{s.cameras_used}, unsigned{s.marks_used}, unsigned{s.pylon_marks_used});
  // Every float with 9 significant digits, the correlations too: enough to read back the very
  // float that was sent (FLT_DECIMAL_DIG), as docs/fti-output.md states.
  const auto write_floats = [this](std::span<const float> values) {
    for (float v : values)
      std::fprintf(file_, ",%.9g", static_cast<double>(v));
  };
  const float values[] = {s.x_m,   s.y_m,   s.z_m,   s.yaw_rad,   s.pitch_rad,   s.roll_rad,
                          s.u_x_m, s.u_y_m, s.u_z_m, s.u_yaw_rad, s.u_pitch_rad, s.u_roll_rad};
  write_floats(values);
  write_floats(s.correlation);
  const float tail[] = {s.u_budget_centroid_m, s.u_budget_intrinsic_m, s.u_budget_extrinsic_m,
                        s.u_budget_sync_m,     s.u_budget_process_m,   s.coverage_factor,
                        s.clearance_m,         s.u_clearance_m,        s.clearance_lower_bound_m};
  write_floats(tail);
  std::fprintf(file_, ",%u", unsigned{s.clearance_part});
  // Line-buffered: the newline writes the row, so a full disk shows here.
  if (std::fputc('\n', file_) == EOF || std::ferror(file_)) {
    std::clearerr(file_);
    return -EIO;
  }
  ++rows_;
  return 0;
}

int FtiCsvWriter::close() {
  if (!file_) return 0;
  const int rc = std::fclose(file_);
  file_ = nullptr;
  return rc == 0 ? 0 : -EIO;
}

}  // namespace storetrack::output
