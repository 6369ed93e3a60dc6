// Is a substituted input's change significant? (storetrack-post --differences-csv;
// docs/post-processing.md, "Significance of a substituted input".) Per sample and per axis of
// (x, y, z, yaw, pitch, roll), the difference of the pose with the substituted input from the
// pose with the recorded one, against the standard uncertainty of that DIFFERENCE: both runs
// see the same observations, so the centroid noise is common and cancels; what differs is the
// substituted input, one independent draw in each run.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <span>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "storetrack/geometry/transform.hpp"
#include "storetrack/pipeline/exposure_result.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::post {

/// Which inputs the second run substitutes.
struct Substituted {
  bool calibration = false, pylon_survey = false, store_survey = false, config = false;
  bool any() const { return calibration || pylon_survey || store_survey || config; }
};

/// One written sample's T_p_s as a difference needs it: the reported quantities and their
/// covariance split by the inputs a substitution can replace.
struct RunPose {
  std::uint32_t trigger_seq = 0;
  time::TaiNs t_ns = 0;
  bool solved = false;  ///< T_p_s solved from this exposure (not extrapolated, not missing)
  geometry::Vec6 value = geometry::Vec6::Zero();  ///< x, y, z [m], yaw, pitch, roll [rad]
  geometry::Mat6 centroid = geometry::Mat6::Zero();
  geometry::Mat6 calibration = geometry::Mat6::Zero();  ///< intrinsic + extrinsic + sync
  geometry::Mat6 pylon_survey = geometry::Mat6::Zero(), store_survey = geometry::Mat6::Zero();
  /// (mark id, camera id, mark index in that camera) of every observation the pose used,
  /// sorted: equal in both runs when the centroid noise is common.
  std::vector<std::array<int, 3>> observations;
  /// The number of columns of the smoother's shared loadings (smooth::PoseMeasurement::shared)
  /// each input loads, in their order: calibration factors, pylon survey, store survey.
  std::array<Eigen::Index, 3> shared_columns{};
  /// The reported quantities' loadings on those factors (through the processor's output
  /// Jacobian), in those columns: a substituted configuration differences them.
  Eigen::Matrix<double, 6, Eigen::Dynamic> shared;
};

/// `pylon_survey_marks`: the number of marks of the pylon survey the processor ran with (its
/// survey loadings' first 3 n columns are the pylon's, the rest the store's).
RunPose run_pose(const pipeline::ExposureResult& r, std::size_t pylon_survey_marks);

/// Var(d) per quantity of the shared errors, from the two runs' loadings (rows: quantities;
/// columns: calibration factors, pylon survey, store survey, `cols_a` and `cols_b` of each): a
/// substituted input is an independent draw in each run (its two parts add), one not
/// substituted the same draw (the difference of its loadings). NaN and `why_not` (a token
/// without commas) when a common input's columns differ between the runs or are missing.
Eigen::VectorXd shared_difference_variance(const Eigen::Ref<const Eigen::MatrixXd>& Ea,
                                           const Eigen::Ref<const Eigen::MatrixXd>& Eb,
                                           const std::array<Eigen::Index, 3>& cols_a,
                                           const std::array<Eigen::Index, 3>& cols_b,
                                           const Substituted& what, std::string& why_not);

struct DifferenceRow {
  std::uint32_t trigger_seq = 0;
  time::TaiNs t_ns = 0;
  bool same_observations = true;  ///< false: the centroid noise does not cancel (bounded, below)
  geometry::Vec6 d = geometry::Vec6::Zero();  ///< substituted - recorded (angles wrapped)
  geometry::Vec6 u = geometry::Vec6::Zero();  ///< NaN when not derived (why_not says why)
  geometry::Vec6 z = geometry::Vec6::Zero();  ///< d / u
  std::string why_not;  ///< empty, or why u is not derived (a substituted configuration's)
};

/// The samples both runs solved, paired by trigger_seq (in the recorded run's order).
std::vector<DifferenceRow> differences(std::span<const RunPose> recorded,
                                       std::span<const RunPose> substituted,
                                       const Substituted& what);

struct AxisSummary {
  std::uint64_t count = 0, above_2 = 0, above_3 = 0;
  double max_abs_z = 0;
  std::uint32_t max_trigger_seq = 0;
  /// Counts one |z| (non-finite: left out, u not derived there).
  void add(double abs_z, std::uint32_t trigger_seq) {
    if (!std::isfinite(abs_z)) return;
    ++count;
    above_2 += abs_z > 2 ? 1 : 0;
    above_3 += abs_z > 3 ? 1 : 0;
    if (abs_z > max_abs_z) {
      max_abs_z = abs_z;
      max_trigger_seq = trigger_seq;
    }
  }
};
/// One axis's (or quantity's) summary in stats.json, and as a line of the printed summary.
nlohmann::json to_json(const AxisSummary& a);
void print_axis(std::FILE* f, const char* name, const AxisSummary& a);

struct DifferenceSummary {
  std::uint64_t recorded = 0, substituted = 0;  ///< written samples of each run
  /// Samples with T_p_s solved in each run: a substitute that loses the store shows here.
  std::uint64_t recorded_solved = 0, substituted_solved = 0;
  std::uint64_t compared = 0;  ///< solved in both
  std::uint64_t different_observations = 0;
  bool derived = true;  ///< false: no row's u derived (a substituted config, columns differ)
  std::array<AxisSummary, 6> axes;
};

DifferenceSummary summarize(std::span<const DifferenceRow> rows, std::span<const RunPose> recorded,
                            std::span<const RunPose> substituted);

/// Header (units) and one line per compared sample; false on a write error.
bool write_differences_csv(std::FILE* f, std::span<const DifferenceRow> rows);
nlohmann::json to_json(const DifferenceSummary& s);
void print_summary(std::FILE* f, const DifferenceSummary& s);

}  // namespace storetrack::post
