// Noise floor of a static record (seed 002, docs/evaluation.md): variance and bias errors per
// axis, the per-sample u the host states for its centroid noise, rig directions.
#include "storetrack/eval/noise_floor.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <optional>
#include <set>

#include "noise_floor_parts.hpp"
#include "rig_observations.hpp"
#include "storetrack/geometry/symmetric_eigen.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::eval {

using geometry::Mat3;
using geometry::Vec3;

RigAxes rig_axes(const camera::RigCalibration& rig) {
  Vec3 view = Vec3::Zero(), centre_mean = Vec3::Zero();
  for (const camera::CalibratedCamera& c : rig.cameras) {
    view += c.T_c_w.linear().transpose().col(2);  // the optical axis (z_c) in the world frame
    centre_mean += camera_centre_w(c);
  }
  RigAxes a;
  a.axis[2] = view.normalized();
  centre_mean /= static_cast<double>(rig.cameras.size());
  // The camera centres' scatter across the viewing direction: its principal direction.
  const Mat3 across = Mat3::Identity() - a.axis[2] * a.axis[2].transpose();
  Mat3 scatter = Mat3::Zero();
  for (const camera::CalibratedCamera& c : rig.cameras) {
    const Vec3 d = across * (camera_centre_w(c) - centre_mean);
    scatter += d * d.transpose();
  }
  const geometry::SymmetricEigen eig = geometry::symmetric_eigen(scatter);
  Vec3 baseline = across * Vec3(eig.vectors.col(2));
  if (baseline.norm() < 1e-9) baseline = across * Vec3::UnitX();  // a single camera position
  // An eigenvector's sign is arbitrary: point it along the world axis it follows most.
  Eigen::Index major = 0;
  baseline.cwiseAbs().maxCoeff(&major);
  a.axis[0] = (baseline(major) < 0 ? -baseline : baseline).normalized();
  a.axis[1] = a.axis[2].cross(a.axis[0]);
  return a;
}

Vec3 camera_centre_w(const camera::CalibratedCamera& c) {
  return -(c.T_c_w.linear().transpose() * c.T_c_w.translation());
}

ChiInterval ratio_interval(std::int64_t dof, double level) {
  const double tail = (1 - level) / 2;
  const uncertainty::DegreesOfFreedom d(static_cast<int>(dof));
  const double n = static_cast<double>(dof);
  return {std::sqrt(uncertainty::chi_square_quantile(uncertainty::Probability(tail), d) / n),
          std::sqrt(uncertainty::chi_square_quantile(uncertainty::Probability(1 - tail), d) / n)};
}

namespace {

[[noreturn]] void fail(const std::string& what) {
  throw EvalInputError(what);
}

/// The stated centroid-only covariance of one sample: its observations triangulated again with
/// the host's own triangulator, rig and weights (so this is the host's cov_centroid, the
/// centroid noise through the estimator's gains). Also the distance to the CSV's position.
std::optional<Mat3> centroid_covariance(const MarkSample& s, const camera::RigCalibration& rig,
                                        const uncertainty::CalibrationFactors& factors,
                                        const std::string& record_path, const std::string& rig_path,
                                        double& offset_m) {
  const std::vector<triangulate::Observation> obs =
      detail::rig_observations(s, rig, factors, record_path, rig_path);
  if (obs.size() < 2) return std::nullopt;
  triangulate::Options options;
  options.calibration_jacobians = false;
  options.initial_p_w = s.p_w;
  triangulate::Result r;
  if (!triangulate::triangulate(obs, options, r)) return std::nullopt;
  offset_m = (r.p_w - s.p_w).norm();
  return r.cov_centroid;
}

/// Per mark: its samples (one per exposure) and, with a rig, their centroid covariances.
struct MarkSeries {
  char body = '?';
  std::vector<const MarkSample*> samples;
  std::vector<Mat3> cov_centroid;  ///< empty unless every sample has one
};

std::map<int, MarkSeries> collect(const MarksRecording& record,
                                  const survey::RigidBodySurvey& reference,
                                  const std::string& survey_path, NoiseFloorResult& result) {
  std::map<int, MarkSeries> series;
  for (const MarkSample& s : record.samples) {
    if (!((s.body == 'p' && result.options.pylon) || (s.body == 's' && result.options.store))) {
      ++result.other_body_samples;
      continue;
    }
    if (!reference.find(s.mark_id))
      fail(record.path + ":" + std::to_string(s.line) + ": mark_id: mark " +
           std::to_string(s.mark_id) + " is not in the survey " + survey_path);
    MarkSeries& m = series[s.mark_id];
    m.body = s.body;
    m.samples.push_back(&s);
  }
  return series;
}

AxisNoise axis_noise(const std::vector<double>& values, double surveyed, double sigma_survey,
                     double u_stated_ms, double u_centroid_ms, const ChiInterval& interval,
                     double k) {
  const double n = static_cast<double>(values.size());
  double mean = 0, ss = 0;
  for (double v : values)
    mean += v / n;
  for (double v : values)
    ss += (v - mean) * (v - mean);
  AxisNoise a;
  a.temporal_sd_m = std::sqrt(ss / (n - 1));
  a.bias_m = mean - surveyed;
  a.u_bias_m = std::sqrt(ss / (n - 1) / n + sigma_survey * sigma_survey);
  a.bias_within_k_u = std::abs(a.bias_m) <= k * a.u_bias_m;
  a.u_stated_m = std::sqrt(u_stated_ms);
  a.u_centroid_m = std::sqrt(u_centroid_ms);
  if (a.u_centroid_m > 0) {
    a.ratio = a.temporal_sd_m / a.u_centroid_m;
    a.agrees = a.ratio >= interval.low && a.ratio <= interval.high;
  }
  return a;
}

MarkNoise evaluate_mark(int id, const MarkSeries& m, const survey::SurveyedMark& surveyed,
                        const NoiseFloorResult& r) {
  MarkNoise out;
  out.mark_id = id;
  out.body = m.body;
  out.samples = static_cast<int>(m.samples.size());
  const ChiInterval interval = ratio_interval(out.samples - 1, r.options.agreement_level);
  out.ratio_low = interval.low;
  out.ratio_high = interval.high;
  for (const MarkSample* s : m.samples)
    out.mean_p_w += s->p_w / out.samples;
  const bool with_centroid = !m.cov_centroid.empty();
  for (int frame = 0; frame < (r.has_rig ? 2 : 1); ++frame) {
    for (int a = 0; a < 3; ++a) {
      const Vec3 dir = frame == 0 ? Vec3::Unit(a) : r.axes.axis[static_cast<size_t>(a)];
      std::vector<double> values;
      double u_stated_ms = 0, u_centroid_ms = 0;
      for (size_t i = 0; i < m.samples.size(); ++i) {
        values.push_back(dir.dot(m.samples[i]->p_w));
        // The CSV states per world axis only: no stated total u along the rig axes.
        if (frame == 0) u_stated_ms += std::pow(m.samples[i]->u_w(a), 2) / out.samples;
        if (with_centroid) u_centroid_ms += dir.dot(m.cov_centroid[i] * dir) / out.samples;
      }
      (frame == 0 ? out.world : out.rig)[static_cast<size_t>(a)] =
          axis_noise(values, dir.dot(surveyed.p_body), surveyed.sigma_m, u_stated_ms, u_centroid_ms,
                     interval, r.options.coverage_factor);
    }
  }
  return out;
}

/// Seed 002's spatial variation: at each exposure the sd over the marks of their displacement
/// from the surveyed position, averaged over the exposures with at least 2 marks.
double spatial_sd_mean(const std::map<int, MarkSeries>& series,
                       const survey::RigidBodySurvey& reference, const std::vector<int>& ids,
                       const Vec3& dir) {
  std::map<std::uint32_t, std::vector<double>> by_exposure;
  for (int id : ids)
    for (const MarkSample* s : series.at(id).samples)
      by_exposure[s->trigger_seq].push_back(dir.dot(s->p_w - reference.find(id)->p_body));
  double sum = 0;
  int count = 0;
  for (const auto& [seq, d] : by_exposure) {
    if (d.size() < 2) continue;
    double mean = 0, ss = 0;
    for (double v : d)
      mean += v / static_cast<double>(d.size());
    for (double v : d)
      ss += (v - mean) * (v - mean);
    sum += std::sqrt(ss / static_cast<double>(d.size() - 1));
    ++count;
  }
  return count ? sum / count : 0;
}

AxisNoiseSummary summarise_axis(const std::vector<MarkNoise>& marks, bool rig_frame, int axis,
                                double level) {
  AxisNoiseSummary s;
  double chi = 0;
  std::int64_t dof = 0;
  const double n = static_cast<double>(marks.size());
  for (const MarkNoise& m : marks) {
    const AxisNoise& a = (rig_frame ? m.rig : m.world)[static_cast<size_t>(axis)];
    s.temporal_sd_mean_m += a.temporal_sd_m / n;
    s.temporal_sd_rms_m += a.temporal_sd_m * a.temporal_sd_m / n;
    s.bias_mean_m += a.bias_m / n;
    s.bias_rms_m += a.bias_m * a.bias_m / n;
    s.bias_max_abs_m = std::max(s.bias_max_abs_m, std::abs(a.bias_m));
    s.u_stated_rms_m += a.u_stated_m * a.u_stated_m / n;
    s.u_centroid_rms_m += a.u_centroid_m * a.u_centroid_m / n;
    s.agreeing_marks += a.agrees ? 1 : 0;
    s.bias_within_k_u += a.bias_within_k_u ? 1 : 0;
    if (a.u_centroid_m > 0) {
      chi += (m.samples - 1) * a.ratio * a.ratio;
      dof += m.samples - 1;
    }
  }
  s.temporal_sd_rms_m = std::sqrt(s.temporal_sd_rms_m);
  s.bias_rms_m = std::sqrt(s.bias_rms_m);
  s.u_stated_rms_m = std::sqrt(s.u_stated_rms_m);
  s.u_centroid_rms_m = std::sqrt(s.u_centroid_rms_m);
  if (dof > 0) {
    s.pooled_ratio = std::sqrt(chi / static_cast<double>(dof));
    const ChiInterval interval = ratio_interval(dof, level);
    s.pooled_low = interval.low;
    s.pooled_high = interval.high;
    s.pooled_dof = dof;
  }
  return s;
}

void check_inputs(const MarksRecording& record, const survey::RigidBodySurvey& reference,
                  const std::string& survey_path, const camera::RigCalibration* rig,
                  const std::string& rig_path, const NoiseFloorOptions& options) {
  if (reference.frame != 'w')
    fail(survey_path + ": frame: '" + std::string(1, reference.frame) +
         "'; the marks' surveyed coordinates must be in the world frame 'w' (the frame of the "
         "marks CSV)");
  if (!options.pylon && !options.store) fail("--body: no body to evaluate; expected p, s or ps");
  if (options.min_samples < 3) fail("--min-samples: must be at least 3");
  if (rig && rig->cameras.empty()) fail(rig_path + ": cameras: the rig has no camera");
  if (rig)
    for (const MarkSample& s : record.samples)
      for (const MarkObservationSample& o : s.observations)
        if (!rig->find(o.camera_id))
          fail(record.path + ":" + std::to_string(s.line) + ": camera_id: camera " +
               std::to_string(o.camera_id) + " is not in the rig " + rig_path);
  std::set<std::uint32_t> exposures;
  for (const MarkSample& s : record.samples)
    exposures.insert(s.trigger_seq);
  if (static_cast<int>(exposures.size()) < options.min_samples)
    fail(record.path + ": trigger_seq: " + std::to_string(exposures.size()) +
         " exposures; the noise floor needs at least " + std::to_string(options.min_samples) +
         " (--min-samples)");
}

}  // namespace

NoiseFloorResult evaluate_noise_floor(const MarksRecording& record,
                                      const survey::RigidBodySurvey& reference,
                                      const std::string& survey_path,
                                      const camera::RigCalibration* rig,
                                      const std::string& rig_path,
                                      const NoiseFloorOptions& options) {
  check_inputs(record, reference, survey_path, rig, rig_path, options);
  NoiseFloorResult r;
  r.options = options;
  r.excluded_rows = record.excluded_rows;
  r.has_rig = rig != nullptr;
  r.has_observations = record.has_observations;
  if (rig) r.axes = rig_axes(*rig);
  std::map<int, MarkSeries> series = collect(record, reference, survey_path, r);
  std::vector<int> ids;
  std::set<std::uint32_t> exposures;
  std::int64_t t_first = INT64_MAX, t_last = 0;
  std::optional<uncertainty::CalibrationFactors> factors;
  for (auto& [id, m] : series) {
    if (static_cast<int>(m.samples.size()) < options.min_samples) {
      r.marks_with_too_few_samples.push_back(id);
      continue;
    }
    ids.push_back(id);
    for (const MarkSample* s : m.samples) {
      exposures.insert(s->trigger_seq);
      t_first = std::min(t_first, s->reference_mid_tai_ns);
      t_last = std::max(t_last, s->reference_mid_tai_ns);
    }
    if (!rig || !record.has_observations) continue;
    if (!factors) factors.emplace(*rig);  // once: the host's weights need the calibration's
    for (const MarkSample* s : m.samples) {
      double offset = 0;
      const std::optional<Mat3> cov =
          centroid_covariance(*s, *rig, *factors, record.path, rig_path, offset);
      if (!cov) {
        m.cov_centroid.clear();  // this mark's stated centroid u stays unknown
        break;
      }
      m.cov_centroid.push_back(*cov);
      r.max_retriangulation_m = std::max(r.max_retriangulation_m, offset);
    }
  }
  if (ids.size() < 2)
    fail(record.path + ": mark_id: " + std::to_string(ids.size()) + " mark(s) of body '" +
         options.bodies() + "' seen in at least " + std::to_string(options.min_samples) +
         " exposures; the noise floor needs at least 2 (spatial variation, distances)");
  r.exposures = static_cast<std::int64_t>(exposures.size());
  if (record.has_time) r.duration_s = static_cast<double>(t_last - t_first) * 1e-9;
  for (int id : ids)
    r.marks.push_back(evaluate_mark(id, series.at(id), *reference.find(id), r));
  std::set<int> seen;  // of any body
  for (const MarkSample& s : record.samples)
    seen.insert(s.mark_id);
  for (const survey::SurveyedMark& m : reference.marks)
    if (!seen.count(m.id)) r.surveyed_marks_not_seen.push_back(m.id);
  for (int a = 0; a < 3; ++a) {
    r.world_summary[static_cast<size_t>(a)] =
        summarise_axis(r.marks, false, a, options.agreement_level);
    r.world_summary[static_cast<size_t>(a)].spatial_sd_mean_m =
        spatial_sd_mean(series, reference, ids, Vec3::Unit(a));
    if (!rig) continue;
    r.rig_summary[static_cast<size_t>(a)] =
        summarise_axis(r.marks, true, a, options.agreement_level);
    r.rig_summary[static_cast<size_t>(a)].spatial_sd_mean_m =
        spatial_sd_mean(series, reference, ids, r.axes.axis[static_cast<size_t>(a)]);
  }
  std::vector<std::vector<const MarkSample*>> evaluated;
  for (int id : ids)
    evaluated.push_back(series.at(id).samples);
  evaluate_image_coordinates(record, evaluated, r);
  if (rig && record.has_observations) evaluate_stereo_angles(evaluated, *rig, r);
  evaluate_distances(evaluated, reference, r);
  return r;
}

}  // namespace storetrack::eval
