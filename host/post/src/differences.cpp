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
constexpr std::array<const char*, 3> kInputs = {"calibration", "pylon_survey", "store_survey"};
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

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
  const Mat6 J = pipeline::output_jacobian(r.T_p_s.T);
  p.shared.resize(6, r.T_p_s.loadings.cols() + L.cols());
  p.shared << J * r.T_p_s.loadings, J * L;
  if (L.cols() > 0) {
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

Eigen::VectorXd shared_difference_variance(const Eigen::Ref<const Eigen::MatrixXd>& Ea,
                                           const Eigen::Ref<const Eigen::MatrixXd>& Eb,
                                           const std::array<Eigen::Index, 3>& cols_a,
                                           const std::array<Eigen::Index, 3>& cols_b,
                                           const Substituted& what, std::string& why_not) {
  const std::array<bool, 3> substituted = {what.calibration, what.pylon_survey, what.store_survey};
  Eigen::VectorXd var = Eigen::VectorXd::Zero(Ea.rows());
  Eigen::Index begin_a = 0, begin_b = 0;
  for (std::size_t i = 0; i < 3; ++i) {
    const Eigen::Index na = cols_a[i], nb = cols_b[i];
    if (begin_a + na > Ea.cols() || begin_b + nb > Eb.cols()) {
      why_not = "not_derived_loadings_missing";
      return Eigen::VectorXd::Constant(Ea.rows(), kNaN);
    }
    if (substituted[i]) {
      var += Ea.middleCols(begin_a, na).rowwise().squaredNorm() +
             Eb.middleCols(begin_b, nb).rowwise().squaredNorm();
    } else if (na == nb) {
      var += (Eb.middleCols(begin_b, nb) - Ea.middleCols(begin_a, na)).rowwise().squaredNorm();
    } else {
      why_not = std::string("not_derived_") + kInputs[i] + "_columns_differ";
      return Eigen::VectorXd::Constant(Ea.rows(), kNaN);
    }
    begin_a += na;
    begin_b += nb;
  }
  return var;
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
  Vec6 var = Vec6::Zero();
  if (what.config) {
    // A substituted configuration changes the processing, not an input: the inputs not
    // substituted are the same draw in both runs, their loadings differenced (the smoothed
    // differences' rule); the weights differ, so the noise does not cancel (bound below).
    var = shared_difference_variance(a.shared, b.shared, a.shared_columns, b.shared_columns, what,
                                     row.why_not);
    if (a.shared.cols() == 0 && row.why_not.empty()) {  // a pose without loadings
      row.why_not = "not_derived_loadings_missing";
      var.setConstant(kNaN);
    }
  } else {
    Mat6 c = Mat6::Zero();
    if (what.calibration) c += a.calibration + b.calibration;
    if (what.pylon_survey) c += a.pylon_survey + b.pylon_survey;
    if (what.store_survey) c += a.store_survey + b.store_survey;
    var = c.diagonal();
  }
  row.same_observations = a.observations == b.observations;
  // Other observations (a mark matched or rejected differently) or other weights: the noise no
  // longer cancels. Var(N_A eps - N_B eps) <= (sd_A + sd_B)^2 per axis (Cauchy-Schwarz), the
  // safe side.
  if (!row.same_observations || what.config)
    var += (a.centroid.diagonal().cwiseSqrt() + b.centroid.diagonal().cwiseSqrt()).cwiseAbs2();
  row.u = var.cwiseSqrt();
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
                            std::span<const RunPose> substituted) {
  DifferenceSummary s;
  s.recorded = recorded.size();
  s.substituted = substituted.size();
  for (const RunPose& p : recorded)
    s.recorded_solved += p.solved ? 1 : 0;
  for (const RunPose& p : substituted)
    s.substituted_solved += p.solved ? 1 : 0;
  s.compared = rows.size();
  s.derived = rows.empty();
  for (const DifferenceRow& r : rows) {
    s.derived = s.derived || r.why_not.empty();
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
    std::fprintf(f, "differences: u not derived (the inputs' factor columns differ): no z\n");
    return;
  }
  for (std::size_t i = 0; i < 6; ++i)
    print_axis(f, kAxes[i], s.axes[i]);
}

}  // namespace storetrack::post
