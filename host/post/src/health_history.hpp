// The calibration health test over a replayed recording (docs/calibration-health.md): one row
// per camera and tested window, read from the chain's guard after each exposure, for the
// report (--report DIR: calibration_health.csv) and the statistic's history the live host only
// logs.
#pragma once

#include <cstdint>
#include <cstdio>
#include <span>
#include <vector>

#include "storetrack/pipeline/calibration_health.hpp"

namespace storetrack::post {

struct HealthWindowRow {
  std::uint32_t trigger_seq = 0;  ///< the exposure that closed the window
  std::int64_t t_tai_ns = 0;      ///< its reference mid-exposure time
  int camera_id = -1;
  std::uint64_t window = 0;  ///< the camera's tested windows so far (1 = the first)
  double statistic = 0;      ///< chi-square(6) of the window's change against the baseline
  double threshold = 0;      ///< the monitor's alarm threshold
  bool moved = false;        ///< declared moved (latched at the first alarm)
};

class HealthHistory {
 public:
  /// After each processed exposure: a row for every camera whose tested-window count grew.
  void observe(const pipeline::CalibrationHealthGuard& guard, std::uint32_t trigger_seq,
               std::int64_t t_tai_ns);
  const std::vector<HealthWindowRow>& rows() const { return rows_; }

 private:
  std::vector<std::uint64_t> windows_seen_;  ///< per camera slot
  std::vector<HealthWindowRow> rows_;
};

/// The rows as CSV with a header; false on a write error.
bool write_health_csv(std::FILE* f, std::span<const HealthWindowRow> rows);

}  // namespace storetrack::post
