// The test-point report's diagnostic tables: --marks-csv (one row per mark observation),
// --rigid-csv (one row per rigid-body pair test) and --clearance-csv (one row per sample and
// aircraft part, storetrack-host and storetrack-post alike). Rows are formatted to text on the
// real-time thread (no I/O there) and written by the RecordingWriter's thread through CsvFile.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>

#include "storetrack/clearance/sample_clearance.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"

namespace storetrack::hostapp {

extern const char* const kMarksCsvHeader;
extern const char* const kRigidCsvHeader;
extern const char* const kClearanceCsvHeader;

/// Appends the rows of one exposure's marks (per observation) to `out`.
void format_marks_rows(const pipeline::AlignedExposure& e, const pipeline::ExposureResult& r,
                       std::string& out);
/// Appends one row per tested pair of `body` ('p' pylon, 's' store) to `out`.
void format_rigid_rows(std::uint32_t trigger_seq, char body, const rigid::RigidCheckResult& c,
                       std::string& out);
/// Appends one row per aircraft part (file order) of the clearance `c` evaluated last, for the
/// sample `s`: `extrapolated` when that pose was the extrapolated one. Only for a sample whose
/// clearance was evaluated (ProcessedExposure::clearance_evaluated).
void format_clearance_rows(const msg::FtiSample& s, bool extrapolated,
                           const clearance::SampleClearance& c, std::string& out);

/// A text file written in whole rows, every write and close checked.
class CsvFile {
 public:
  CsvFile() = default;
  ~CsvFile();
  CsvFile(const CsvFile&) = delete;
  CsvFile& operator=(const CsvFile&) = delete;
  /// Creates `path` (a new file: output::fopen_new_file) with `header` (one line, without
  /// newline); 0 or -errno.
  int open(const std::string& path, const char* header, bool number_if_exists = true);
  const std::string& path() const { return path_; }  ///< the file created
  bool is_open() const { return file_ != nullptr; }
  /// Writes `rows` (whole lines); 0 or -errno, errors counted.
  int write(const std::string& rows);
  /// 0 or -errno (fclose flushes the buffered rows, so a full disk may show only here).
  int close();
  std::uint64_t bytes_written() const { return bytes_; }
  std::uint64_t write_errors() const { return errors_; }  ///< failed write() calls only

 private:
  std::FILE* file_ = nullptr;
  std::string path_;
  std::uint64_t bytes_ = 0, errors_ = 0;
};

}  // namespace storetrack::hostapp
