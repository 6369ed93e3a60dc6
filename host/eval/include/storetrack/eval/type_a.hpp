// SisTrO static Type A evaluation (docs/evaluation.md; GUM JCGM 100:2008 sec. 4.2): N repeated
// static recordings of reference marks against their total-station coordinates in the world
// frame. Per mark and axis: mean error, experimental standard deviation of the repetitions'
// values, standard uncertainty of the mean s/sqrt(N), expanded uncertainty k*u, and whether the
// instrument's stated per-sample uncertainty agrees with the repetitions' scatter.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "storetrack/eval/marks_csv.hpp"
#include "storetrack/survey/survey.hpp"

namespace storetrack::eval {

struct TypeAOptions {
  char body = 'p';                ///< marks of this body are evaluated ('p' pylon, 's' store)
  double coverage_factor = 2;     ///< k of the expanded uncertainty U = k u
  double agreement_level = 0.95;  ///< two-sided level of the chi-square interval of s / u_stated
};

/// One mark on one axis.
struct AxisTypeA {
  double mean_error_m = 0;  ///< mean of the repetitions' values minus the surveyed coordinate
  double sd_m = 0;          ///< experimental standard deviation s of the repetitions' values
  double u_mean_m = 0;      ///< s / sqrt(N): Type A standard uncertainty of the mean
  double expanded_m = 0;    ///< k * u_mean
  double u_stated_m = 0;    ///< RMS over repetitions of the host's stated per-sample u
  double u_survey_m = 0;    ///< the survey's sigma_m (the reference's own uncertainty)
  double ratio = 0;         ///< s / u_stated
  bool agrees = false;      ///< ratio inside [ratio_low, ratio_high]
};

struct MarkTypeA {
  int mark_id = 0;
  int repetitions = 0;                   ///< N: repetitions that saw this mark
  int samples = 0;                       ///< exposures over all repetitions
  double ratio_low = 0, ratio_high = 0;  ///< sqrt(chi2_{(1-+level)/2}(N-1) / (N-1))
  std::array<AxisTypeA, 3> axis;         ///< x, y, z of the world frame
};

/// The per-axis summary (SisTrO's static table): over the evaluated marks.
struct AxisSummary {
  double mean_error_m = 0;    ///< mean over marks of the mean error
  double sd_rms_m = 0;        ///< RMS over marks of s (the pooled 1-sigma of one repetition)
  double sd_max_m = 0;        ///< largest s ("better than" statement)
  double u_stated_rms_m = 0;  ///< RMS over marks of u_stated
  int agreeing_marks = 0;
};

struct TypeAResult {
  TypeAOptions options;
  int repetitions = 0;                         ///< recordings read
  std::vector<MarkTypeA> marks;                ///< marks seen in >= 2 repetitions, ascending id
  std::vector<int> marks_with_one_repetition;  ///< counted, not evaluated
  std::vector<int> surveyed_marks_not_seen;
  std::array<AxisSummary, 3> summary;
  std::int64_t other_body_samples = 0, excluded_rows = 0;
};

/// Throws EvalInputError: fewer than 2 recordings, a survey not in the world frame, a mark of
/// the evaluated body absent from the survey, no mark seen twice.
TypeAResult evaluate_type_a(const std::vector<MarksRecording>& recordings,
                            const survey::RigidBodySurvey& reference,
                            const std::string& survey_path, const TypeAOptions& options = {});

}  // namespace storetrack::eval
