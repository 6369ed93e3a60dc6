// Runs from the marks CSVs and the identification's initial values: the plane by PCA of all
// mark positions, the pivot and radii by an algebraic (Kasa) circle fit with one centre, and the
// dynamics by a linear least-squares fit of the angular acceleration of one mark,
//   psi'' = A sin(psi) + B cos(psi) + C psi',  psi = theta - delta,
// so omega0^2 = hypot(A, B) and delta (= theta0, psi being 0 while held) = atan2(-B, -A).
#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <string>

#include <Eigen/Dense>

#include "pendulum_internal.hpp"
#include "storetrack/geometry/symmetric_eigen.hpp"

namespace storetrack::eval {

using geometry::Vec3;

namespace {

/// A mark has moved off its held angle once the board turned by this much (1.5 mm at 0.5 m,
/// far above the ~0.1 mm noise of a triangulated mark).
constexpr double kMotionThresholdRad = 3e-3;

/// Before any geometry is fitted (a circle through a short arc is ill-conditioned): the board
/// has been released once a mark left its first position by this much.
constexpr double kMotionThresholdM = 1.5e-3;

[[noreturn]] void too_short(const std::string& path, const std::string& why) {
  throw EvalInputError(path + ": run too short to identify the pendulum: " + why);
}

double wrap_pi(double a) {
  return std::remainder(a, 2 * M_PI);
}

struct PlaneBasis {
  Vec3 e1, e2;
};

PlaneBasis plane_basis(const Vec3& n, const Vec3& down) {
  const Vec3 e1 = down - down.dot(n) * n;
  if (e1.norm() < 0.1)
    throw EvalInputError(
        "pendulum: the swing plane is (near) horizontal: gravity does not drive the swing");
  PlaneBasis b;
  b.e1 = e1.normalized();
  b.e2 = n.cross(b.e1);
  return b;
}

/// Unwrapped angle of mark `slot` in the plane per unique time of the run (NaN where unseen).
std::vector<double> mark_angles(const detail::PreparedRun& r, int slot, const Vec3& c,
                                const PlaneBasis& b) {
  std::vector<double> alpha(r.times_s.size(), std::numeric_limits<double>::quiet_NaN());
  for (size_t i = 0; i < r.run->samples.size(); ++i) {
    if (r.mark_slot[i] != slot) continue;
    const Vec3 q = r.run->samples[i].p_w - c;
    alpha[static_cast<size_t>(r.time_index[i])] = std::atan2(q.dot(b.e2), q.dot(b.e1));
  }
  double previous = std::numeric_limits<double>::quiet_NaN();
  for (double& a : alpha) {
    if (std::isnan(a)) continue;
    if (!std::isnan(previous)) a = previous + wrap_pi(a - previous);
    previous = a;
  }
  return alpha;
}

int reference_slot(const detail::PreparedRun& r, size_t marks) {
  std::vector<int> count(marks, 0);
  for (int s : r.mark_slot)
    ++count[static_cast<size_t>(s)];
  return static_cast<int>(std::max_element(count.begin(), count.end()) - count.begin());
}

struct RunDynamics {
  double omega0_sq = 0, theta0 = 0, release_s = 0;
  bool clockwise = true;
};

/// The release (first turn beyond the threshold), then the linear fit of psi''.
RunDynamics run_dynamics(const std::vector<double>& t, const std::vector<double>& alpha,
                         const std::string& path, int min_after) {
  std::vector<double> ts, psi;
  for (size_t k = 0; k < t.size(); ++k)
    if (!std::isnan(alpha[k])) {
      ts.push_back(t[k]);
      psi.push_back(alpha[k]);
    }
  if (psi.size() < 3) too_short(path, "its reference mark is seen in fewer than 3 exposures");
  const double held = psi.front();
  for (double& p : psi)
    p -= held;
  const auto moved = std::find_if(psi.begin(), psi.end(),
                                  [](double p) { return std::abs(p) > kMotionThresholdRad; });
  if (moved == psi.end()) {
    double most = 0;
    for (double p : psi)
      most = std::max(most, std::abs(p));
    too_short(path, "no release seen (the board turns by at most " +
                        std::to_string(most * 180 / M_PI) + " deg)");
  }
  const size_t k_move = static_cast<size_t>(moved - psi.begin());
  if (k_move < 2 || std::abs(psi[1]) > kMotionThresholdRad)
    too_short(path, "the recording starts after the release (no held exposure before it)");
  const size_t after = psi.size() - k_move;
  if (static_cast<int>(after) < min_after)
    too_short(path, std::to_string(after) + " exposures after the release, at least " +
                        std::to_string(min_after) + " needed (--min-exposures-after-release)");
  const size_t stride = std::max<size_t>(1, after / 60);
  Eigen::MatrixXd A(0, 3);
  Eigen::VectorXd y(0);
  for (size_t k = k_move; k + stride < psi.size(); k += stride) {
    const double h1 = ts[k] - ts[k - stride], h2 = ts[k + stride] - ts[k];
    const double acc =
        2 * ((psi[k + stride] - psi[k]) / h2 - (psi[k] - psi[k - stride]) / h1) / (h1 + h2);
    const double rate = (psi[k + stride] - psi[k - stride]) / (h1 + h2);
    A.conservativeResize(A.rows() + 1, 3);
    y.conservativeResize(y.rows() + 1);
    A.row(A.rows() - 1) << std::sin(psi[k]), std::cos(psi[k]), rate;
    y(y.rows() - 1) = acc;
  }
  const Eigen::Vector3d x = A.colPivHouseholderQr().solve(y);
  RunDynamics d;
  d.omega0_sq = std::hypot(x(0), x(1));
  d.theta0 = std::atan2(-x(1), -x(0));
  const double accel0 = d.omega0_sq * std::abs(std::sin(d.theta0));
  d.release_s =
      accel0 > 1e-6 ? ts[k_move] - std::sqrt(2 * std::abs(psi[k_move]) / accel0) : ts[k_move - 1];
  d.release_s = std::clamp(d.release_s, ts.front(), ts[k_move]);
  d.clockwise = psi.back() < 0;
  return d;
}

/// Pivot (in the plane through `mean`) and each mark's radius: |q|^2 = 2 q.c + (r_i^2 - |c|^2).
void circle_fit(const std::vector<detail::PreparedRun>& runs, size_t marks, const Vec3& mean,
                const PlaneBasis& b, Vec3& pivot, std::vector<std::array<double, 3>>& mark) {
  size_t rows = 0;
  for (const auto& r : runs)
    rows += r.run->samples.size();
  Eigen::MatrixXd A =
      Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(rows), static_cast<Eigen::Index>(2 + marks));
  Eigen::VectorXd y(static_cast<Eigen::Index>(rows));
  Eigen::Index row = 0;
  for (const auto& r : runs)
    for (size_t i = 0; i < r.run->samples.size(); ++i, ++row) {
      const Vec3 q = r.run->samples[i].p_w - mean;
      const double u = q.dot(b.e1), v = q.dot(b.e2);
      A(row, 0) = 2 * u;
      A(row, 1) = 2 * v;
      A(row, 2 + r.mark_slot[i]) = 1;
      y(row) = u * u + v * v;
    }
  const Eigen::VectorXd x = A.colPivHouseholderQr().solve(y);
  pivot = mean + x(0) * b.e1 + x(1) * b.e2;
  for (size_t m = 0; m < marks; ++m)
    mark[m][0] =
        std::sqrt(std::max(1e-6, x(static_cast<Eigen::Index>(2 + m)) + x(0) * x(0) + x(1) * x(1)));
}

}  // namespace

std::vector<PendulumRun> pendulum_runs(const std::vector<MarksRecording>& recordings,
                                       const PendulumOptions& options) {
  std::vector<PendulumRun> runs;
  for (const MarksRecording& rec : recordings) {
    if (!rec.has_time)
      throw EvalInputError(rec.path +
                           ":1: reference_mid_tai_ns: missing column in the header (the "
                           "pendulum needs each exposure's time)");
    PendulumRun run;
    run.path = rec.path;
    for (const MarkSample& s : rec.samples)
      if (s.body == options.body)
        run.samples.push_back(s);
      else
        ++run.other_body_samples;
    run.excluded_rows = rec.excluded_rows;
    if (run.samples.empty())
      throw EvalInputError(rec.path + ": body: no sample of body '" + std::string(1, options.body) +
                           "' (the pendulum's marks, --body)");
    run.origin_tai_ns = run.samples.front().reference_mid_tai_ns;
    for (const MarkSample& s : run.samples)
      run.origin_tai_ns = std::min(run.origin_tai_ns, s.reference_mid_tai_ns);
    runs.push_back(std::move(run));
  }
  return runs;
}

namespace detail {

std::vector<PreparedRun> prepare_runs(const std::vector<PendulumRun>& runs,
                                      std::vector<int>& mark_ids) {
  mark_ids.clear();
  for (const PendulumRun& r : runs)
    for (const MarkSample& s : r.samples)
      mark_ids.push_back(s.mark_id);
  std::sort(mark_ids.begin(), mark_ids.end());
  mark_ids.erase(std::unique(mark_ids.begin(), mark_ids.end()), mark_ids.end());
  std::vector<PreparedRun> out;
  for (const PendulumRun& r : runs) {
    PreparedRun p;
    p.run = &r;
    std::map<std::int64_t, int> times;
    for (const MarkSample& s : r.samples)
      times.emplace(s.reference_mid_tai_ns, 0);
    int index = 0;
    for (auto& [tai, i] : times) {
      i = index++;
      p.times_s.push_back(static_cast<double>(tai - r.origin_tai_ns) * 1e-9);
    }
    for (const MarkSample& s : r.samples) {
      p.time_index.push_back(times.at(s.reference_mid_tai_ns));
      p.mark_slot.push_back(static_cast<int>(
          std::lower_bound(mark_ids.begin(), mark_ids.end(), s.mark_id) - mark_ids.begin()));
    }
    std::vector<int> seen(mark_ids.size(), 0);
    for (int s : p.mark_slot)
      seen[static_cast<size_t>(s)] = 1;
    if (std::count(seen.begin(), seen.end(), 1) < 3)
      too_short(r.path, "fewer than 3 marks of the pendulum seen");
    std::map<int, Vec3> first;
    double moved = 0;
    for (const MarkSample& s : r.samples) {
      const auto [it, inserted] = first.emplace(s.mark_id, s.p_w);
      moved = std::max(moved, (s.p_w - it->second).norm());
    }
    if (moved < kMotionThresholdM)
      too_short(r.path, "no release seen (no mark moves by more than " +
                            std::to_string(moved * 1e3) + " mm)");
    out.push_back(std::move(p));
  }
  return out;
}

PendulumState initial_state(const std::vector<PreparedRun>& runs, const std::vector<int>& mark_ids,
                            const PendulumOptions& options) {
  const size_t marks = mark_ids.size();
  Vec3 mean = Vec3::Zero();
  size_t count = 0;
  for (const auto& r : runs)
    for (const MarkSample& s : r.run->samples) {
      mean += s.p_w;
      ++count;
    }
  mean /= static_cast<double>(count);
  Eigen::MatrixXd scatter = Eigen::MatrixXd::Zero(3, 3);
  for (const auto& r : runs)
    for (const MarkSample& s : r.run->samples)
      scatter += (s.p_w - mean) * (s.p_w - mean).transpose();
  Vec3 n = geometry::symmetric_eigen(scatter).vectors.col(0);
  const Vec3 down = options.down_w.normalized();
  PlaneBasis b = plane_basis(n, down);
  PendulumState st;
  st.mark_ids = mark_ids;
  st.mark.assign(marks, {0, 0, 0});
  Vec3 pivot;
  circle_fit(runs, marks, mean, b, pivot, st.mark);
  // n is oriented so that run 0 turns clockwise (theta decreasing) about it.
  const int ref0 = reference_slot(runs[0], marks);
  if (!run_dynamics(runs[0].times_s, mark_angles(runs[0], ref0, pivot, b), runs[0].run->path,
                    options.min_exposures_after_release)
           .clockwise) {
    n = -n;
    b = plane_basis(n, down);
  }
  double omega0_sq_sum = 0;
  std::vector<bool> phi_set(marks, false);
  for (const auto& r : runs) {
    const int ref = reference_slot(r, marks);
    const std::vector<double> alpha_ref = mark_angles(r, ref, pivot, b);
    const RunDynamics d =
        run_dynamics(r.times_s, alpha_ref, r.run->path, options.min_exposures_after_release);
    omega0_sq_sum += d.omega0_sq;
    st.run.push_back({d.theta0, d.release_s});
    st.clockwise.push_back(d.clockwise);
    // theta(t) = alpha_ref(t) - alpha_ref(first) + theta0 where the reference mark is seen.
    double first = std::numeric_limits<double>::quiet_NaN();
    for (double a : alpha_ref)
      if (std::isnan(first) && !std::isnan(a)) first = a;
    for (size_t m = 0; m < marks; ++m) {
      if (phi_set[m]) continue;
      const std::vector<double> alpha = mark_angles(r, static_cast<int>(m), pivot, b);
      for (size_t k = 0; k < alpha.size(); ++k)
        if (!std::isnan(alpha[k]) && !std::isnan(alpha_ref[k])) {
          st.mark[m][1] = wrap_pi(alpha[k] - (alpha_ref[k] - first + d.theta0));
          phi_set[m] = true;
          break;
        }
    }
  }
  std::vector<double> h_sum(marks, 0), h_count(marks, 0);
  for (const auto& r : runs)
    for (size_t i = 0; i < r.run->samples.size(); ++i) {
      const auto m = static_cast<size_t>(r.mark_slot[i]);
      h_sum[m] += (r.run->samples[i].p_w - pivot).dot(n);
      h_count[m] += 1;
    }
  const double h0 = h_sum[0] / h_count[0];
  pivot += h0 * n;  // the pivot lies in the plane of the first mark (h = 0 there)
  for (size_t m = 0; m < marks; ++m)
    st.mark[m][2] = h_count[m] > 0 ? h_sum[m] / h_count[m] - h0 : 0;
  st.shared = {options.g_m_s2 / (omega0_sq_sum / static_cast<double>(runs.size())), 0.0};
  for (int k = 0; k < 3; ++k) {
    st.pivot[static_cast<size_t>(k)] = pivot(k);
    st.normal[static_cast<size_t>(k)] = n(k);
  }
  return st;
}

}  // namespace detail
}  // namespace storetrack::eval
