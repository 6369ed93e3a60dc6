// VDI/VDE 2634-1 length measuring error from the host's triangulated scale-bar marks.
#include "storetrack/eval/length_measuring_error.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <utility>

#include "rig_observations.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "storetrack/uncertainty/calibration_factors.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::eval {
namespace {

using Key = std::pair<std::uint32_t, int>;  // (trigger_seq, mark id)

std::string mark_role(const survey::ScaleBar& bar, int id) {
  return "bar '" + bar.id + "' " + (id == bar.mark_a ? "mark_a" : "mark_b");
}

/// The samples of one file by (exposure, mark); refuses a bar mark with one camera row or no
/// triangulated position at all.
std::map<Key, const MarkSample*> index_bar_marks(const MarksRecording& rec,
                                                 const survey::ScaleBarSet& bars,
                                                 const std::string& bars_path) {
  std::map<Key, const MarkSample*> index;
  std::map<int, const survey::ScaleBar*> bar_of;
  for (const survey::ScaleBar& b : bars.bars) {
    bar_of[b.mark_a] = &b;
    bar_of[b.mark_b] = &b;
  }
  std::map<int, int> seen;
  for (const MarkSample& s : rec.samples) {
    const auto it = bar_of.find(s.mark_id);
    if (it == bar_of.end()) continue;
    if (s.camera_rows < 2)
      throw EvalInputError(rec.path + ":" + std::to_string(s.line) + ": camera_id: mark " +
                           std::to_string(s.mark_id) + " (" + mark_role(*it->second, s.mark_id) +
                           " of " + bars_path + ") of trigger_seq " +
                           std::to_string(s.trigger_seq) +
                           " has one camera row: a triangulated position needs 2 cameras");
    index[{s.trigger_seq, s.mark_id}] = &s;
    ++seen[s.mark_id];
  }
  for (const auto& [id, bar] : bar_of)
    if (!seen.count(id))
      throw EvalInputError(
          rec.path + ": mark_id: mark " + std::to_string(id) + " (" + mark_role(*bar, id) + " of " +
          bars_path +
          ") has no triangulated position in any exposure: the host writes a mark seen by at "
          "least 2 cameras (a bar seen by one camera, occluded or unidentified has none)");
  return index;
}

/// The rig the host measured with and its calibration factors (the ends' shared error).
struct SharedCalibration {
  const camera::RigCalibration* rig = nullptr;
  uncertainty::CalibrationFactors factors;
};

/// A mark's loadings on the calibration factors: its observations (the CSV's pixels and sigma)
/// triangulated again with the host's triangulator from the CSV's position, then the host's
/// loadings of each observation. Throws when a camera is not in the rig or the point is lost.
uncertainty::Loadings3 calibration_loadings(const MarkSample& s, const SharedCalibration& cal,
                                            const std::string& path) {
  std::vector<int> slots;
  const std::vector<triangulate::Observation> obs =
      detail::rig_observations(s, *cal.rig, cal.factors, path, "calibration", &slots);
  triangulate::Options options;
  options.initial_p_w = s.p_w;
  triangulate::Result tri;
  if (!triangulate::triangulate(obs, options, tri))
    throw EvalInputError(path + ":" + std::to_string(s.line) + ": u_obs, v_obs: mark " +
                         std::to_string(s.mark_id) +
                         " cannot be triangulated again with the rig calibration");
  uncertainty::Loadings3 loadings = uncertainty::Loadings3::Zero(3, cal.factors.num_factors());
  Eigen::Matrix3d unused_intrinsic = Eigen::Matrix3d::Zero(), unused_extrinsic = unused_intrinsic;
  for (size_t i = 0; i < obs.size(); ++i)
    uncertainty::add_observation_loadings(cal.factors, slots[i], tri.gain[i], tri.jacobians[i],
                                          loadings, unused_intrinsic, unused_extrinsic);
  return loadings;
}

LengthMeasurement measure(const MarkSample& a, const MarkSample& b, const survey::ScaleBar& bar,
                          int repetition, const SharedCalibration* cal, const std::string& path) {
  LengthMeasurement m;
  m.repetition = repetition;
  m.trigger_seq = a.trigger_seq;
  m.p_a_w = a.p_w;
  m.p_b_w = b.p_w;
  const geometry::Vec3 ab = b.p_w - a.p_w;
  m.measured_m = ab.norm();
  m.error_m = m.measured_m - bar.length_m;
  const geometry::Vec3 d = ab / m.measured_m;
  double variance = d.dot((a.cov_w + b.cov_w) * d) + bar.u_length_m * bar.u_length_m;
  if (cal) {
    const Eigen::RowVectorXd la = d.transpose() * calibration_loadings(a, *cal, path);
    const Eigen::RowVectorXd lb = d.transpose() * calibration_loadings(b, *cal, path);
    variance -= 2 * la.dot(lb);
  }
  m.u_m = std::sqrt(std::max(variance, 0.0));
  return m;
}

LmeStatistics statistics(const std::vector<const LengthMeasurement*>& ms, const LmeOptions& o,
                         const std::vector<double>& mpe_m) {
  LmeStatistics s;
  s.n = static_cast<int>(ms.size());
  if (s.n == 0) return s;
  double z2 = 0, u2 = 0;
  for (size_t i = 0; i < ms.size(); ++i) {
    const LengthMeasurement& m = *ms[i];
    s.mean_m += m.error_m;
    s.max_abs_m = std::max(s.max_abs_m, std::abs(m.error_m));
    z2 += m.error_m * m.error_m / (m.u_m * m.u_m);
    u2 += m.u_m * m.u_m;
    if (o.mpe.assessed && std::abs(m.error_m) > mpe_m[i]) ++s.exceeding_mpe;
  }
  s.mean_m /= s.n;
  double ss = 0;
  for (const LengthMeasurement* m : ms)
    ss += (m->error_m - s.mean_m) * (m->error_m - s.mean_m);
  s.sd_m = s.n > 1 ? std::sqrt(ss / (s.n - 1)) : 0;
  s.u_rms_m = std::sqrt(u2 / s.n);
  s.z_rms = std::sqrt(z2 / s.n);
  const double tail = (1 - o.consistency_level) / 2;
  const uncertainty::DegreesOfFreedom dof(s.n);
  s.z_rms_low =
      std::sqrt(uncertainty::chi_square_quantile(uncertainty::Probability(tail), dof) / s.n);
  s.z_rms_high =
      std::sqrt(uncertainty::chi_square_quantile(uncertainty::Probability(1 - tail), dof) / s.n);
  return s;
}

/// Measurements of every bar in every exposure where both of its marks were triangulated.
void collect(const std::vector<MarksRecording>& recordings, const survey::ScaleBarSet& bars,
             const std::string& bars_path, const SharedCalibration* cal, LmeResult& result) {
  for (const survey::ScaleBar& b : bars.bars)
    result.bars.push_back(BarLme{b, {}, 0, 0, 0, {}, {}, {}});
  for (size_t r = 0; r < recordings.size(); ++r) {
    const MarksRecording& rec = recordings[r];
    result.excluded_rows += rec.excluded_rows;
    if (cal && !rec.has_observations)
      throw EvalInputError(rec.path + ":1: " + rec.missing_observation_columns.front() +
                           ": missing column in the header (the ends' shared calibration "
                           "error needs each mark's observations; or give no rig)");
    const std::map<Key, const MarkSample*> index = index_bar_marks(rec, bars, bars_path);
    for (BarLme& bl : result.bars) {
      const size_t before = bl.measurements.size();
      for (const auto& [key, a] : index) {
        if (key.second != bl.bar.mark_a) continue;
        const auto b = index.find({key.first, bl.bar.mark_b});
        if (b == index.end()) {
          ++bl.incomplete_exposures;
          continue;
        }
        result.full_covariance =
            result.full_covariance && a->full_covariance && b->second->full_covariance;
        bl.measurements.push_back(
            measure(*a, *b->second, bl.bar, static_cast<int>(r), cal, rec.path));
      }
      for (const auto& [key, b] : index)  // mark_b without mark_a
        if (key.second == bl.bar.mark_b && !index.count({key.first, bl.bar.mark_a}))
          ++bl.incomplete_exposures;
      if (bl.measurements.size() > before) ++bl.repetitions;
    }
  }
}

}  // namespace

LmeResult evaluate_lme(const std::vector<MarksRecording>& recordings,
                       const survey::ScaleBarSet& bars, const std::string& bars_path,
                       const LmeOptions& options) {
  if (recordings.empty()) throw EvalInputError("recordings: no marks CSV given");
  LmeResult result;
  result.options = options;
  std::optional<SharedCalibration> cal;
  if (options.rig)
    cal = SharedCalibration{&*options.rig, uncertainty::CalibrationFactors(*options.rig)};
  result.shared_calibration = cal.has_value();
  collect(recordings, bars, bars_path, cal ? &*cal : nullptr, result);
  std::vector<const LengthMeasurement*> all;
  std::vector<double> all_mpe;
  std::vector<std::vector<const LengthMeasurement*>> per_rep(recordings.size());
  std::vector<std::vector<double>> per_rep_mpe(recordings.size());
  for (BarLme& bl : result.bars) {
    if (bl.repetitions < options.min_repetitions)
      throw EvalInputError(bars_path + ": bars: bar '" + bl.bar.id + "' measured in " +
                           std::to_string(bl.repetitions) + " of the " +
                           std::to_string(recordings.size()) +
                           " marks CSV (both marks in one exposure); at least " +
                           std::to_string(options.min_repetitions) +
                           " repetitions are required (--min-repetitions)");
    bl.mpe_m = options.mpe.assessed ? options.mpe.at(bl.bar.length_m) : 0;
    std::vector<const LengthMeasurement*> ms;
    for (const LengthMeasurement& m : bl.measurements) {
      ms.push_back(&m);
      all.push_back(&m);
      all_mpe.push_back(bl.mpe_m);
      per_rep[static_cast<size_t>(m.repetition)].push_back(&m);
      per_rep_mpe[static_cast<size_t>(m.repetition)].push_back(bl.mpe_m);
      bl.p_a_w += m.p_a_w;
      bl.p_b_w += m.p_b_w;
    }
    bl.p_a_w /= static_cast<double>(ms.size());
    bl.p_b_w /= static_cast<double>(ms.size());
    bl.stats = statistics(ms, options, std::vector<double>(ms.size(), bl.mpe_m));
  }
  for (size_t r = 0; r < recordings.size(); ++r)
    result.repetitions.push_back(
        {recordings[r].path, statistics(per_rep[r], options, per_rep_mpe[r])});
  result.overall = statistics(all, options, all_mpe);
  result.pass = options.mpe.assessed && result.overall.exceeding_mpe == 0;
  return result;
}

}  // namespace storetrack::eval
