// storetrack-post --report DIR: the directory (new or empty, never over a file) and the report's
// tables in it, which host/report/storetrack_post_report.py renders (docs/post-processing.md).
#pragma once

#include <cstdio>
#include <span>
#include <string>

#include <nlohmann/json.hpp>

#include "recording.hpp"
#include "replay.hpp"
#include "report_data.hpp"

namespace storetrack::post {

/// Exposures per residual window (5 s at 400 fps is 2000: windows of 0.05 s).
inline constexpr int kResidualWindowExposures = 20;

/// Creates `dir`, or accepts an existing empty directory; throws std::runtime_error naming it
/// when it holds anything or is not a directory.
void prepare_report_dir(const std::string& dir);

/// The recording's integrity (per file: packets, checksum errors, sequence gaps, torn; between
/// files: packets missing; the replay's refused and undecodable records; exposures missing
/// from the trigger sequence).
nlohmann::json integrity_json(const Recording& r, const ReplayCounters& c,
                              std::span<const ExposureRow> exposures);

/// residuals.csv, residual_windows.csv, exposures.csv and report.json (the noise windows', the
/// calibration part's and the rigid fits' summary, the integrity) in `dir`. Returns false (errno
/// set) when a write failed.
bool write_report_tables(const std::string& dir, const Recording& r, const ReplayCounters& c,
                         std::span<const CameraResidualRow> residuals,
                         std::span<const ExposureRow> exposures,
                         std::span<const CalibrationResidual> calibration,
                         const nlohmann::json& files);

}  // namespace storetrack::post
