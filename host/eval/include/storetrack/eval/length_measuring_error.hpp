// VDI/VDE 2634-1 length measuring error (docs/evaluation.md): calibrated scale bars in the
// guideline's positions across the measuring volume, measured by the instrument (the host's
// marks CSV, one file per repetition). Per bar and exposure: the measured length |p_b - p_a| of
// the triangulated marks, LME = measured - calibrated, and its predicted standard uncertainty
//   u^2 = d^T (S_a + S_b) d + u_bar^2,   d = (p_b - p_a) / |p_b - p_a|,
// with S_a, S_b the host's stated covariances of the two marks (per-axis only when the file
// lacks the cov_*_w columns: the approximation is flagged) and u_bar the bar's calibration u.
// The two ends share the calibration error (a rig translation moves them alike, a focal-length
// error moves them apart), which per-mark rows cannot carry. Given the rig calibration the
// host used (LmeOptions::rig), each end is triangulated again from its observations with the
// host's triangulator and its loadings L on the calibration factors computed with the host's
// own code (uncertainty::add_observation_loadings), and
//   u^2 = d^T (S_a + S_b) d - 2 (L_a^T d) . (L_b^T d) + u_bar^2
// (the shared calibration error cancels in the difference). Without a rig the cross term is
// left out (independent ends: u overstated when the calibration dominates), and flagged.
// Per bar, per repetition and overall: max |LME|, mean, sigma (seed 001's table), pass/fail
// against the maximum permissible error MPE = A + L/K or a constant.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/eval/marks_csv.hpp"
#include "storetrack/survey/scale_bars.hpp"

namespace storetrack::eval {

/// The maximum permissible length measuring error, MPE(L) = a_m + L / k (VDI/VDE 2634-1 form)
/// or the constant a_m (k = 0); not assessed when `assessed` is false.
struct MaximumPermissibleError {
  bool assessed = false;
  double a_m = 0;  ///< [m]
  double k = 0;    ///< [1]; 0: constant MPE
  double at(double length_m) const { return k > 0 ? a_m + length_m / k : a_m; }
};

struct LmeOptions {
  MaximumPermissibleError mpe;
  /// The rig calibration the host measured with (its covariance): the ends' shared calibration
  /// error enters u. Empty: the ends are treated as independent.
  std::optional<camera::RigCalibration> rig;
  int min_repetitions = 3;          ///< marks CSVs in which every bar must be measured
  double consistency_level = 0.95;  ///< two-sided level of the RMS(LME/u) interval
};

/// One bar in one exposure of one repetition.
struct LengthMeasurement {
  int repetition = 0;  ///< index into the marks CSVs
  std::uint32_t trigger_seq = 0;
  double measured_m = 0;
  double error_m = 0;  ///< LME = measured - calibrated
  double u_m = 0;      ///< predicted standard uncertainty of LME (marks and bar)
  geometry::Vec3 p_a_w = geometry::Vec3::Zero(), p_b_w = geometry::Vec3::Zero();
};

/// max |LME|, mean, experimental standard deviation (N - 1) over a set of measurements, and
/// the RMS of LME / u with its chi-square interval (independent measurements assumed).
struct LmeStatistics {
  int n = 0;
  double max_abs_m = 0, mean_m = 0, sd_m = 0;
  double u_rms_m = 0;                    ///< RMS of the predicted u
  double z_rms = 0;                      ///< sqrt(mean(LME^2 / u^2))
  double z_rms_low = 0, z_rms_high = 0;  ///< sqrt(chi2_{(1-+level)/2}(n) / n)
  int exceeding_mpe = 0;                 ///< measurements with |LME| > MPE(L)
};

struct BarLme {
  survey::ScaleBar bar;
  std::vector<LengthMeasurement> measurements;
  int repetitions = 0;                    ///< marks CSVs with at least one measurement
  std::int64_t incomplete_exposures = 0;  ///< exposures with one of the two marks only
  double mpe_m = 0;                       ///< MPE at the calibrated length (0: not assessed)
  LmeStatistics stats;
  geometry::Vec3 p_a_w = geometry::Vec3::Zero(), p_b_w = geometry::Vec3::Zero();  ///< means
};

struct RepetitionLme {
  std::string path;
  LmeStatistics stats;
};

struct LmeResult {
  LmeOptions options;
  std::vector<BarLme> bars;                ///< in the order of the bar file
  std::vector<RepetitionLme> repetitions;  ///< one per marks CSV
  LmeStatistics overall;
  bool full_covariance = true;      ///< every sample carried its off-diagonal covariance
  bool shared_calibration = false;  ///< u has the ends' shared calibration error (a rig given)
  bool pass = false;                ///< every |LME| <= MPE(L) (only when options.mpe.assessed)
  std::int64_t excluded_rows = 0;
};

/// Throws EvalInputError naming the file and field: no marks CSV, a bar's mark without a
/// triangulated position in a whole file (not seen by 2 cameras), a bar mark with one camera
/// row, a bar measured in fewer than options.min_repetitions files.
LmeResult evaluate_lme(const std::vector<MarksRecording>& recordings,
                       const survey::ScaleBarSet& bars, const std::string& bars_path,
                       const LmeOptions& options = {});

}  // namespace storetrack::eval
