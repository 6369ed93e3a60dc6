// GUM Type A (JCGM 100:2008 sec. 4.2) over repeated static recordings, per mark and axis.
#include "storetrack/eval/type_a.hpp"

#include <algorithm>
#include <cmath>
#include <map>

#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::eval {
namespace {

/// One repetition's value of one mark: the mean over its exposures, and the RMS of the stated
/// per-sample u (the instrument's claim for one sample).
struct RepetitionValue {
  geometry::Vec3 sum = geometry::Vec3::Zero(), u2_sum = geometry::Vec3::Zero();
  int samples = 0;
};

using Repetitions = std::map<int, std::vector<RepetitionValue>>;  // mark id -> one per recording

Repetitions collect(const std::vector<MarksRecording>& recordings,
                    const survey::RigidBodySurvey& reference, const std::string& survey_path,
                    const TypeAOptions& options, TypeAResult& result) {
  Repetitions reps;
  for (const MarksRecording& rec : recordings) {
    std::map<int, RepetitionValue> values;
    for (const MarkSample& s : rec.samples) {
      if (s.body != options.body) {
        ++result.other_body_samples;
        continue;
      }
      if (!reference.find(s.mark_id))
        throw EvalInputError(rec.path + ":" + std::to_string(s.line) + ": mark_id: mark " +
                             std::to_string(s.mark_id) + " is not in the survey " + survey_path);
      RepetitionValue& v = values[s.mark_id];
      v.sum += s.p_w;
      v.u2_sum += s.u_w.cwiseAbs2();
      ++v.samples;
    }
    for (const auto& [id, v] : values)
      reps[id].push_back(v);
    result.excluded_rows += rec.excluded_rows;
  }
  return reps;
}

MarkTypeA evaluate_mark(int id, const std::vector<RepetitionValue>& values,
                        const survey::SurveyedMark& surveyed, const TypeAOptions& options) {
  MarkTypeA m;
  m.mark_id = id;
  m.repetitions = static_cast<int>(values.size());
  const int n = m.repetitions;
  const uncertainty::DegreesOfFreedom dof(n - 1);
  const double tail = (1 - options.agreement_level) / 2;
  m.ratio_low =
      std::sqrt(uncertainty::chi_square_quantile(uncertainty::Probability(tail), dof) / (n - 1));
  m.ratio_high = std::sqrt(
      uncertainty::chi_square_quantile(uncertainty::Probability(1 - tail), dof) / (n - 1));
  geometry::Vec3 mean = geometry::Vec3::Zero(), u2 = geometry::Vec3::Zero();
  for (const RepetitionValue& v : values) {
    mean += v.sum / v.samples;
    u2 += v.u2_sum / v.samples;
    m.samples += v.samples;
  }
  mean /= n;
  u2 /= n;
  geometry::Vec3 ss = geometry::Vec3::Zero();
  for (const RepetitionValue& v : values)
    ss += (v.sum / v.samples - mean).cwiseAbs2();
  for (int a = 0; a < 3; ++a) {
    AxisTypeA& ax = m.axis[static_cast<size_t>(a)];
    ax.mean_error_m = mean(a) - surveyed.p_body(a);
    ax.sd_m = std::sqrt(ss(a) / (n - 1));
    ax.u_mean_m = ax.sd_m / std::sqrt(static_cast<double>(n));
    ax.expanded_m = options.coverage_factor * ax.u_mean_m;
    ax.u_stated_m = std::sqrt(u2(a));
    ax.u_survey_m = surveyed.sigma_m;
    ax.ratio = ax.sd_m / ax.u_stated_m;
    ax.agrees = ax.ratio >= m.ratio_low && ax.ratio <= m.ratio_high;
  }
  return m;
}

void summarise(TypeAResult& r) {
  for (int a = 0; a < 3; ++a) {
    AxisSummary& s = r.summary[static_cast<size_t>(a)];
    for (const MarkTypeA& m : r.marks) {
      const AxisTypeA& ax = m.axis[static_cast<size_t>(a)];
      s.mean_error_m += ax.mean_error_m;
      s.sd_rms_m += ax.sd_m * ax.sd_m;
      s.sd_max_m = std::max(s.sd_max_m, ax.sd_m);
      s.u_stated_rms_m += ax.u_stated_m * ax.u_stated_m;
      s.agreeing_marks += ax.agrees ? 1 : 0;
    }
    const double n = static_cast<double>(r.marks.size());
    s.mean_error_m /= n;
    s.sd_rms_m = std::sqrt(s.sd_rms_m / n);
    s.u_stated_rms_m = std::sqrt(s.u_stated_rms_m / n);
  }
}

}  // namespace

TypeAResult evaluate_type_a(const std::vector<MarksRecording>& recordings,
                            const survey::RigidBodySurvey& reference,
                            const std::string& survey_path, const TypeAOptions& options) {
  if (recordings.size() < 2)
    throw EvalInputError("recordings: " + std::to_string(recordings.size()) +
                         " marks CSV given; Type A needs at least 2 repetitions");
  if (reference.frame != 'w')
    throw EvalInputError(survey_path + ": frame: '" + std::string(1, reference.frame) +
                         "'; the reference marks' total-station coordinates must be in the "
                         "world frame 'w' (the frame of the marks CSV)");
  TypeAResult result;
  result.options = options;
  result.repetitions = static_cast<int>(recordings.size());
  const Repetitions reps = collect(recordings, reference, survey_path, options, result);
  for (const auto& [id, values] : reps) {
    if (values.size() < 2) {
      result.marks_with_one_repetition.push_back(id);
      continue;
    }
    result.marks.push_back(evaluate_mark(id, values, *reference.find(id), options));
  }
  for (const survey::SurveyedMark& m : reference.marks)
    if (!reps.count(m.id)) result.surveyed_marks_not_seen.push_back(m.id);
  if (result.marks.empty())
    throw EvalInputError("recordings: no mark of body '" + std::string(1, options.body) +
                         "' seen in at least 2 of the " + std::to_string(recordings.size()) +
                         " marks CSV");
  summarise(result);
  return result;
}

}  // namespace storetrack::eval
