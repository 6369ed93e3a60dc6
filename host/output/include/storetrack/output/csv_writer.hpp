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

class FtiCsvWriter {
 public:
  FtiCsvWriter() = default;
  ~FtiCsvWriter();
  FtiCsvWriter(const FtiCsvWriter&) = delete;
  FtiCsvWriter& operator=(const FtiCsvWriter&) = delete;
  /// Creates the file and writes the header; returns 0 or -errno.
  int open(const std::string& path);
  int write(const msg::FtiSample& sample);
  int close();
  std::uint64_t rows_written() const { return rows_; }

 private:
  std::FILE* file_ = nullptr;
  std::uint64_t rows_ = 0;
};

}  // namespace storetrack::output
