#include "smoothed_differences.hpp"

#include <cmath>
#include <limits>
#include <map>

namespace storetrack::post {

namespace {

using Quantities = Eigen::Matrix<double, kSmoothedOutputs, 1>;
using QuantityLoadings = Eigen::Matrix<double, kSmoothedOutputs, Eigen::Dynamic>;

/// A smoothed state with its exposure's written sample (the same reference mid-time).
struct Paired {
  const smooth::SmoothedState* state = nullptr;
  const RunPose* pose = nullptr;
};

std::map<std::uint32_t, Paired> by_trigger(const SmoothedRun& run) {
  std::map<time::TaiNs, const RunPose*> by_time;
  for (const RunPose& p : run.poses)
    by_time[p.t_ns] = &p;
  std::map<std::uint32_t, Paired> out;
  for (const smooth::SmoothedState& s : run.states)
    if (const auto it = by_time.find(s.t_ns); it != by_time.end())
      out[it->second->trigger_seq] = {&s, it->second};
  return out;
}

/// The recording's shared columns per input (the same in every solved exposure of a run).
std::array<Eigen::Index, 3> columns_of(const SmoothedRun& run) {
  for (const RunPose& p : run.poses)
    if (p.solved) return p.shared_columns;
  return {};
}

/// The same information at this exposure: solved or predicted alike, the same observations,
/// the same modelled acceleration step.
bool same_information(const Paired& a, const Paired& b) {
  return a.state->measured == b.state->measured && a.state->step == b.state->step &&
         a.pose->observations == b.pose->observations;
}

/// Per segment of `x`: true when each of its exposures has one in `y` with the same
/// information. The smoother's gain at any exposure depends on the whole segment's.
std::map<int, bool> segments_alike(const std::map<std::uint32_t, Paired>& x,
                                   const std::map<std::uint32_t, Paired>& y) {
  std::map<int, bool> alike;
  for (const auto& [seq, a] : x) {
    bool& ok = alike.try_emplace(a.state->segment, true).first->second;
    const auto it = y.find(seq);
    ok = ok && it != y.end() && same_information(a, it->second);
  }
  return alike;
}

Quantities values_and_loadings(const smooth::SmoothedState& s, QuantityLoadings& E,
                               Quantities& sd_noise) {
  std::array<double, kSmoothedOutputs> v{};
  SmoothedOutputMap M;
  smoothed_outputs(s, v, M);
  E = M * s.shared;
  sd_noise = (M * s.cov_noise * M.transpose()).diagonal().cwiseMax(0).cwiseSqrt();
  return Eigen::Map<const Quantities>(v.data());
}

struct Layouts {
  std::array<Eigen::Index, 3> a{}, b{};
};

SmoothedDifferenceRow difference(const Paired& a, const Paired& b, const Layouts& cols,
                                 const Substituted& what, bool noise_cancels) {
  SmoothedDifferenceRow row;
  row.trigger_seq = a.pose->trigger_seq;
  row.t_ns = a.state->t_ns;
  row.segment = a.state->segment;
  QuantityLoadings Ea, Eb;
  Quantities sd_a, sd_b;
  const Quantities va = values_and_loadings(*a.state, Ea, sd_a);
  const Quantities vb = values_and_loadings(*b.state, Eb, sd_b);
  Quantities d = vb - va;
  for (int i = 3; i < 6; ++i)  // yaw, pitch, roll
    d(i) = std::remainder(d(i), 2 * M_PI);
  Quantities var = shared_difference_variance(Ea, Eb, cols.a, cols.b, what, row.why_not);
  // The noise (centroid noise and the model's process noise) is one draw in both runs; with
  // the same observations and steps over the segment and the same configuration, the gains
  // differ only through the linearisation point (second order): it cancels. Otherwise
  // Var(a - b) <= (sd_a + sd_b)^2 (Cauchy-Schwarz), the safe side.
  if (!noise_cancels || what.config) {
    row.basis = DifferenceBasis::kNoiseBound;
    var += (sd_a + sd_b).cwiseAbs2();
  }
  if (!row.why_not.empty()) row.basis = DifferenceBasis::kNotDerived;
  const Quantities u = var.cwiseSqrt();
  for (int i = 0; i < kSmoothedOutputs; ++i) {
    const auto k = static_cast<std::size_t>(i);
    row.d[k] = d(i);
    row.u[k] = u(i);
    row.z[k] = d(i) / u(i);
  }
  return row;
}

const char* basis_name(const SmoothedDifferenceRow& r) {
  switch (r.basis) {
    case DifferenceBasis::kNoiseCancels:
      return "noise_cancels";
    case DifferenceBasis::kNoiseBound:
      return "noise_bound";
    default:
      return r.why_not.c_str();
  }
}

}  // namespace

std::vector<SmoothedDifferenceRow> smoothed_differences(const SmoothedRun& recorded,
                                                        const SmoothedRun& substituted,
                                                        const Substituted& what) {
  const std::map<std::uint32_t, Paired> a = by_trigger(recorded), b = by_trigger(substituted);
  const std::map<int, bool> alike_a = segments_alike(a, b), alike_b = segments_alike(b, a);
  const Layouts cols{columns_of(recorded), columns_of(substituted)};
  std::vector<SmoothedDifferenceRow> rows;
  for (const auto& [seq, x] : a) {
    const auto y = b.find(seq);
    if (y == b.end()) continue;
    const bool cancels = alike_a.at(x.state->segment) && alike_b.at(y->second.state->segment);
    rows.push_back(difference(x, y->second, cols, what, cancels));
  }
  return rows;
}

SmoothedDifferenceSummary summarize(std::span<const SmoothedDifferenceRow> rows,
                                    const SmoothedRun& recorded, const SmoothedRun& substituted) {
  SmoothedDifferenceSummary s;
  s.recorded = recorded.states.size();
  s.substituted = substituted.states.size();
  s.compared = rows.size();
  for (const SmoothedDifferenceRow& r : rows) {
    s.noise_bound += r.basis == DifferenceBasis::kNoiseBound ? 1 : 0;
    s.not_derived += r.basis == DifferenceBasis::kNotDerived ? 1 : 0;
    for (std::size_t i = 0; i < kSmoothedOutputs; ++i)
      s.quantities[i].add(std::abs(r.z[i]), r.trigger_seq);
  }
  return s;
}

bool write_smoothed_differences_csv(std::FILE* f, std::span<const SmoothedDifferenceRow> rows) {
  bool ok = std::fputs("trigger_seq,t_tai_ns,segment,u_basis", f) >= 0;
  for (const char* n : kSmoothedNames)
    ok = ok && std::fprintf(f, ",d_%s,u_d_%s,z_%s,sig_k2_%s", n, n, n, n) > 0;
  ok = ok && std::fputc('\n', f) != EOF;
  for (const SmoothedDifferenceRow& r : rows) {
    ok = ok && std::fprintf(f, "%u,%lld,%d,%s", r.trigger_seq, static_cast<long long>(r.t_ns),
                            r.segment, basis_name(r)) > 0;
    for (std::size_t i = 0; i < kSmoothedOutputs; ++i)
      ok = ok && std::fprintf(f, ",%.9g,%.9g,%.4f,%d", r.d[i], r.u[i], r.z[i],
                              std::abs(r.z[i]) > kSignificanceK ? 1 : 0) > 0;
    ok = ok && std::fputc('\n', f) != EOF;
  }
  return ok;
}

nlohmann::json to_json(const SmoothedDifferenceSummary& s) {
  nlohmann::json j = {{"recorded_states", s.recorded},
                      {"substituted_states", s.substituted},
                      {"compared", s.compared},
                      {"noise_bound", s.noise_bound},
                      {"not_derived", s.not_derived}};
  for (std::size_t i = 0; i < kSmoothedOutputs; ++i)
    j["quantities"][kSmoothedNames[i]] = to_json(s.quantities[i]);
  return j;
}

void print_summary(std::FILE* f, const SmoothedDifferenceSummary& s) {
  std::fprintf(f,
               "smoothed differences: %llu exposures smoothed in both runs (%llu recorded, %llu "
               "substituted); u with the noise bound on %llu, not derived on %llu\n",
               static_cast<unsigned long long>(s.compared),
               static_cast<unsigned long long>(s.recorded),
               static_cast<unsigned long long>(s.substituted),
               static_cast<unsigned long long>(s.noise_bound),
               static_cast<unsigned long long>(s.not_derived));
  for (std::size_t i = 0; i < kSmoothedOutputs; ++i)
    print_axis(f, kSmoothedNames[i], s.quantities[i]);
}

}  // namespace storetrack::post
