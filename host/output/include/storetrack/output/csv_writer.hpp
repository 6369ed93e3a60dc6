// CSV of FtiSamples for analysis: a header naming every column with its unit in brackets,
// one row per sample, full float precision. Column list: docs/fti-output.md, "CSV".
#pragma once

#include <cstdio>
#include <string>
#include <vector>

#include "storetrack/msg/messages.hpp"

namespace storetrack::output {

/// Column names with units, in file order.
std::vector<std::string> fti_csv_columns();

/// Creates a NEW file for writing (never opens an existing one): `path`, or when it exists and
/// `number_if_exists`, the first free numbered name (out.csv -> out.001.csv .. out.999.csv, as
/// for Chapter 10 files). Returns the stream (nullptr and errno set: EEXIST when refused or no
/// free number) and the name created in `created`. An existing FIFO or device is opened as it
/// is (it holds no recording).
std::FILE* fopen_new_file(const std::string& path, bool number_if_exists, std::string& created);

class FtiCsvWriter {
 public:
  FtiCsvWriter() = default;
  ~FtiCsvWriter();
  FtiCsvWriter(const FtiCsvWriter&) = delete;
  FtiCsvWriter& operator=(const FtiCsvWriter&) = delete;
  /// Creates the file (a new one: fopen_new_file) and writes the header; returns 0 or -errno.
  int open(const std::string& path, bool number_if_exists = true);
  const std::string& path() const { return path_; }  ///< the file created
  int write(const msg::FtiSample& sample);
  int close();
  std::uint64_t rows_written() const { return rows_; }

 private:
  std::FILE* file_ = nullptr;
  std::string path_;
  std::uint64_t rows_ = 0;
};

}  // namespace storetrack::output
