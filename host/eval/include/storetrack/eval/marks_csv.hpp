// Reader of the host's --marks-csv (docs/fti-output.md; writer: host/app/src/diagnostic_csv.cpp):
// one row per mark observation (per camera), so a mark's triangulated world position appears
// once per camera that saw it; the reader keeps one sample per (trigger_seq, mark_id).
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "storetrack/geometry/transform.hpp"

namespace storetrack::eval {

/// Bad evaluation input; what() names the file (and line) and the field, and why.
class EvalInputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// One camera's sighting of a mark (the marks CSV's optional observation columns): the
/// centroid, its reprojection residual against the triangulated point, its stated sigma.
struct MarkObservationSample {
  int camera_id = 0;
  geometry::Vec2 pixel_px = geometry::Vec2::Zero();     ///< (u_obs, v_obs); NaN if not written
  geometry::Vec2 residual_px = geometry::Vec2::Zero();  ///< observed - reprojected
  double sigma_px = 0;                                  ///< centroid standard uncertainty
};

/// One mark in one exposure: the host's triangulated world position and its stated per-axis
/// standard uncertainty.
struct MarkSample {
  std::uint32_t trigger_seq = 0;
  int mark_id = 0;
  char body = '?';                              ///< 'p' pylon, 's' store, '?' unidentified body
  geometry::Vec3 p_w = geometry::Vec3::Zero();  ///< [m]
  geometry::Vec3 u_w = geometry::Vec3::Zero();  ///< standard uncertainty per axis [m]
  /// Stated covariance [m^2]: u_w^2 on the diagonal; the off-diagonal terms when the file has
  /// the cov_xy_w, cov_xz_w, cov_yz_w columns (`full_covariance`), else zero.
  geometry::Mat3 cov_w = geometry::Mat3::Zero();
  bool full_covariance = false;
  int camera_rows = 1;  ///< rows of this sample (one per camera that saw the mark)
  int line = 0;         ///< first CSV line of this sample (messages)
  std::int64_t reference_mid_tai_ns = 0;  ///< 0 when the column is absent
  /// One per row (camera) of this sample, when the CSV has the observation columns.
  std::vector<MarkObservationSample> observations;
};

struct MarksRecording {
  std::string path;
  std::vector<MarkSample> samples;  ///< excluded marks left out (the host did not use them)
  std::int64_t excluded_rows = 0;   ///< rows the host flagged excluded (counted, not used)
  /// The optional columns camera_id, u_obs, v_obs, residual_u, residual_v, sigma were all
  /// present (MarkSample::observations filled); else the names of those missing.
  bool has_observations = false;
  std::vector<std::string> missing_observation_columns;
  bool has_time = false;  ///< reference_mid_tai_ns present
};

/// Reads a marks CSV; throws EvalInputError on a missing column, a malformed or non-finite value
/// or a file without samples.
MarksRecording read_marks_csv(const std::string& path);
/// The same from text; `origin` names the file in messages.
MarksRecording parse_marks_csv(const std::string& text, const std::string& origin);

}  // namespace storetrack::eval
