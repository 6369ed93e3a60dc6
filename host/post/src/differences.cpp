#include "differences.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

#include "storetrack/pipeline/pose_output.hpp"

namespace storetrack::post {

namespace {

using geometry::Mat6;
using geometry::Vec6;
using uncertainty::Source;

constexpr std::array<const char*, 6> kAxes = {"x", "y", "z", "yaw", "pitch", "roll"};
constexpr std::array<const char*, 6> kUnits = {"m", "m", "m", "rad", "rad", "rad"};

const Mat6& part(const pipeline::ExposureResult& r, Source s) {
  return r.cov_xyz_ypr_by_source[static_cast<std::size_t>(uncertainty::index(s))];
}

std::vector<std::array<int, 3>> observations_used(const pipeline::ExposureResult& r) {
  std::vector<std::array<int, 3>> out;
  for (const pipeline::MarkResult& m : r.marks) {
    if (m.excluded || (m.body != 'p' && m.body != 's')) continue;
    for (const auto& o : m.observations)
      out.push_back({m.id, o.camera_id, o.mark_index});
  }
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace

RunPose run_pose(const pipeline::ExposureResult& r, std::size_t pylon_survey_marks) {
  RunPose p;
  p.trigger_seq = r.trigger_seq;
  p.t_ns = r.reference_mid_tai_ns;
  p.solved = r.T_p_s.valid && !r.extrapolated;
  if (!p.solved) return p;
  p.value = r.xyz_ypr;
  p.centroid = part(r, Source::kCentroid);
  p.calibration =
      part(r, Source::kIntrinsic) + part(r, Source::kExtrinsic) + part(r, Source::kSync);
  // The survey part split by survey: its loadings' columns, the pylon's first, through the
  // same Jacobian the processor applies to the pose covariance.
  const uncertainty::Loadings6& L = r.T_p_s.survey_loadings;
  const auto n_p = static_cast<Eigen::Index>(
      std::min<std::size_t>(3 * pylon_survey_marks, static_cast<std::size_t>(L.cols())));
  p.shared_columns = {r.T_p_s.loadings.cols(), n_p, L.cols() - n_p};
  if (L.cols() > 0) {
    const Mat6 J = pipeline::output_jacobian(r.T_p_s.T);
    const Eigen::Matrix<double, 6, Eigen::Dynamic> Lp = J * L.leftCols(n_p);
    const Eigen::Matrix<double, 6, Eigen::Dynamic> Ls = J * L.rightCols(L.cols() - n_p);
    p.pylon_survey = Lp * Lp.transpose();
    p.store_survey = Ls * Ls.transpose();
  } else {  // no loadings (Monte Carlo draws): each survey stated with the whole part
    p.pylon_survey = p.store_survey = part(r, Source::kSurvey);
  }
  p.observations = observations_used(r);
  return p;
}

// Cov(d) per axis. The recorded run's error is e_A = M_A z_A + S_A s_A + N eps, the substituted
// run's e_B = M_B z_B + S_B s_B + N eps (first order): the centroid noise eps is the same
// observations' in both and cancels; a substituted input is an independent draw, so its two
// parts add; an input not substituted is the same draw in both and cancels.
DifferenceRow difference(const RunPose& a, const RunPose& b, const Substituted& what) {
  DifferenceRow row;
  row.trigger_seq = a.trigger_seq;
  row.t_ns = a.t_ns;
  row.d = b.value - a.value;
  for (int i = 3; i < 6; ++i)
    row.d(i) = std::remainder(row.d(i), 2 * M_PI);
  Mat6 c = Mat6::Zero();
  if (what.calibration) c += a.calibration + b.calibration;
  if (what.pylon_survey) c += a.pylon_survey + b.pylon_survey;
  if (what.store_survey) c += a.store_survey + b.store_survey;
  Vec6 var = c.diagonal();
  row.same_observations = a.observations == b.observations;
  // Other observations (a mark matched or rejected differently): the noise no longer cancels.
  // Var(N_A eps - N_B eps) <= (sd_A + sd_B)^2 per axis (Cauchy-Schwarz), the safe side.
  if (!row.same_observations)
    var += (a.centroid.diagonal().cwiseSqrt() + b.centroid.diagonal().cwiseSqrt()).cwiseAbs2();
  row.u = what.config ? Vec6(Vec6::Constant(std::numeric_limits<double>::quiet_NaN()))
                      : Vec6(var.cwiseSqrt());
  row.z = row.d.cwiseQuotient(row.u);
  return row;
}

std::vector<DifferenceRow> differences(std::span<const RunPose> recorded,
                                       std::span<const RunPose> substituted,
                                       const Substituted& what) {
  std::map<std::uint32_t, const RunPose*> by_seq;
  for (const RunPose& b : substituted)
    if (b.solved) by_seq[b.trigger_seq] = &b;
  std::vector<DifferenceRow> rows;
  for (const RunPose& a : recorded) {
    const auto it = by_seq.find(a.trigger_seq);
    if (a.solved && it != by_seq.end()) rows.push_back(difference(a, *it->second, what));
  }
  return rows;
}

DifferenceSummary summarize(std::span<const DifferenceRow> rows, std::span<const RunPose> recorded,
                            std::span<const RunPose> substituted, const Substituted& what) {
  DifferenceSummary s;
  s.recorded = recorded.size();
  s.substituted = substituted.size();
  for (const RunPose& p : recorded)
    s.recorded_solved += p.solved ? 1 : 0;
  for (const RunPose& p : substituted)
    s.substituted_solved += p.solved ? 1 : 0;
  s.compared = rows.size();
  s.derived = !what.config;
  for (const DifferenceRow& r : rows) {
    s.different_observations += r.same_observations ? 0 : 1;
    for (std::size_t i = 0; i < 6; ++i)
      s.axes[i].add(std::abs(r.z(static_cast<Eigen::Index>(i))), r.trigger_seq);
  }
  return s;
}

bool write_differences_csv(std::FILE* f, std::span<const DifferenceRow> rows) {
  bool ok = std::fputs("trigger_seq,t_tai_ns,same_observations", f) >= 0;
  for (std::size_t i = 0; i < 6; ++i)
    ok = ok && std::fprintf(f, ",d_%s_%s,u_d_%s_%s,z_%s", kAxes[i], kUnits[i], kAxes[i], kUnits[i],
                            kAxes[i]) > 0;
  ok = ok && std::fputc('\n', f) != EOF;
  for (const DifferenceRow& r : rows) {
    ok = ok && std::fprintf(f, "%u,%lld,%d", r.trigger_seq, static_cast<long long>(r.t_ns),
                            r.same_observations ? 1 : 0) > 0;
    for (Eigen::Index i = 0; i < 6; ++i)
      ok = ok && std::fprintf(f, ",%.9g,%.9g,%.4f", r.d(i), r.u(i), r.z(i)) > 0;
    ok = ok && std::fputc('\n', f) != EOF;
  }
  return ok;
}

nlohmann::json to_json(const DifferenceSummary& s) {
  nlohmann::json j = {{"recorded_samples", s.recorded},
                      {"substituted_samples", s.substituted},
                      {"recorded_solved", s.recorded_solved},
                      {"substituted_solved", s.substituted_solved},
                      {"compared", s.compared},
                      {"different_observations", s.different_observations},
                      {"u_derived", s.derived}};
  for (std::size_t i = 0; i < 6; ++i)
    j["axes"][kAxes[i]] = to_json(s.axes[i]);
  return j;
}

nlohmann::json to_json(const AxisSummary& a) {
  return {{"count", a.count},
          {"abs_z_above_2", a.above_2},
          {"abs_z_above_3", a.above_3},
          {"max_abs_z", a.max_abs_z},
          {"max_abs_z_trigger_seq", a.max_trigger_seq}};
}

void print_axis(std::FILE* f, const char* name, const AxisSummary& a) {
  std::fprintf(f, "  %-13s |z| > 2: %llu, > 3: %llu of %llu; max |z| %.2f (trigger_seq %u)\n", name,
               static_cast<unsigned long long>(a.above_2),
               static_cast<unsigned long long>(a.above_3), static_cast<unsigned long long>(a.count),
               a.max_abs_z, a.max_trigger_seq);
}

void print_summary(std::FILE* f, const DifferenceSummary& s) {
  std::fprintf(f,
               "differences: %llu samples solved in both runs (written %llu recorded, %llu "
               "substituted; store solved in %llu and %llu), %llu with other observations\n",
               static_cast<unsigned long long>(s.compared),
               static_cast<unsigned long long>(s.recorded),
               static_cast<unsigned long long>(s.substituted),
               static_cast<unsigned long long>(s.recorded_solved),
               static_cast<unsigned long long>(s.substituted_solved),
               static_cast<unsigned long long>(s.different_observations));
  if (!s.derived) {
    std::fprintf(f, "differences: a substituted configuration states no uncertainty: no z\n");
    return;
  }
  for (std::size_t i = 0; i < 6; ++i)
    print_axis(f, kAxes[i], s.axes[i]);
}

}  // namespace storetrack::post
