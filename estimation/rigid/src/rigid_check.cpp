#include "storetrack/rigid/rigid_check.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>

#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::rigid {

using geometry::Vec3;

namespace {

// Bonferroni per-pair threshold: chi-square(1) quantile at 1 - alpha / pairs. The inverse
// incomplete gamma function costs as much as a few dozen pair tests and the same few values
// recur every exposure, so the last ones are kept (per thread: no locking).
double pair_threshold(double alpha, size_t pairs) {
  struct Entry {
    double alpha = -1;
    size_t pairs = 0;
    double threshold = 0;
  };
  thread_local std::array<Entry, 16> cache{};
  thread_local size_t next = 0;
  for (const Entry& e : cache)
    if (e.alpha == alpha && e.pairs == pairs) return e.threshold;
  Entry& e = cache[next];
  next = (next + 1) % cache.size();
  e.alpha = alpha;
  e.pairs = pairs;
  e.threshold = uncertainty::chi_square_quantile(
      uncertainty::Probability(1.0 - alpha / static_cast<double>(pairs)),
      uncertainty::DegreesOfFreedom(1));
  return e.threshold;
}

// ((d - d_survey) / sigma)^2, infinite for an error without variance.
double normalised_square(double error, double var) {
  return var > 0 ? error * error / var : (error == 0 ? 0 : INFINITY);
}

// The pair's distance, its surveyed distance and the direction of p_a - p_b.
PairTest pair_geometry(const MarkEstimate& a, const MarkEstimate& b, Vec3& u) {
  PairTest t;
  t.id_a = a.id;
  t.id_b = b.id;
  const Vec3 d = a.p_w - b.p_w;
  t.distance_m = d.norm();
  t.surveyed_m = (a.p_body - b.p_body).norm();
  u = t.distance_m > 0 ? Vec3(d / t.distance_m) : Vec3::UnitX();
  return t;
}

double survey_variance(const MarkEstimate& a, const MarkEstimate& b) {
  return a.survey_sigma_m * a.survey_sigma_m + b.survey_sigma_m * b.survey_sigma_m;
}

// |u^T (L_a - L_b)|^2 over the common factors: a combination of the loadings' rows (row-major,
// contiguous: one vectorised pass, no temporaries; hot loop over all pairs).
double shared_variance(const MarkEstimate& a, const MarkEstimate& b, const Vec3& u) {
  const auto* La = a.loadings;
  const auto* Lb = b.loadings;
  if (La != nullptr && Lb != nullptr)
    return (u(0) * (La->row(0) - Lb->row(0)) + u(1) * (La->row(1) - Lb->row(1)) +
            u(2) * (La->row(2) - Lb->row(2)))
        .squaredNorm();
  if (La == nullptr && Lb == nullptr) return 0;
  const auto* L = La != nullptr ? La : Lb;
  return (u(0) * L->row(0) + u(1) * L->row(1) + u(2) * L->row(2)).squaredNorm();
}

// Variance of the distance error short of the shared calibration part: both marks' own parts.
double private_variance(const MarkEstimate& a, const MarkEstimate& b, const Vec3& u) {
  return u.dot((a.cov_independent + b.cov_independent) * u);
}

// The full variance of the distance error: independent parts add, the common calibration part
// enters through L_a - L_b, and both survey sigmas.
double pair_variance(const MarkEstimate& a, const MarkEstimate& b, const Vec3& u,
                     double var_private) {
  return var_private + shared_variance(a, b, u) + survey_variance(a, b);
}

// Does every pair pass the threshold? A pair's shared calibration variance is formed only when
// it fails without it: the variance short of that non-negative term is a lower bound of the
// full one (rounding is monotonic), so its z2 an upper bound of the full test's.
bool all_pairs_pass(std::span<const MarkEstimate> marks, double threshold) {
  for (size_t i = 0; i < marks.size(); ++i)
    for (size_t j = i + 1; j < marks.size(); ++j) {
      const MarkEstimate &a = marks[i], &b = marks[j];
      Vec3 u;
      const PairTest t = pair_geometry(a, b, u);
      const double e = t.distance_m - t.surveyed_m;
      const double var_private = private_variance(a, b, u);
      if (normalised_square(e, var_private + survey_variance(a, b)) <= threshold) continue;
      if (normalised_square(e, pair_variance(a, b, u, var_private)) > threshold) return false;
    }
  return true;
}

}  // namespace

PairTest test_pair(const MarkEstimate& a, const MarkEstimate& b) {
  Vec3 u;
  PairTest t = pair_geometry(a, b, u);
  const double var = pair_variance(a, b, u, private_variance(a, b, u));
  t.sigma_m = std::sqrt(var);
  t.z2 = normalised_square(t.distance_m - t.surveyed_m, var);
  return t;
}

void check_rigid_body(std::span<const MarkEstimate> marks, const RigidCheckConfig& config,
                      RigidCheckResult& result) {
  if (!(config.false_alarm_probability > 0 && config.false_alarm_probability < 1))
    throw std::invalid_argument("rigid check: false_alarm_probability must be in (0, 1)");
  result.pairs.clear();
  result.excluded_ids.clear();
  result.excluded.clear();
  result.failed = false;
  result.consistent_after = true;
  result.pair_threshold_z2 = 0;
  const size_t n = marks.size();
  result.mean_z2.assign(n, 0.0);
  if (!config.pair_statistics && n >= 2) {
    const double threshold = pair_threshold(config.false_alarm_probability, n * (n - 1) / 2);
    if (all_pairs_pass(marks, threshold)) {
      result.pair_threshold_z2 = threshold;
      return;
    }
  }
  for (size_t i = 0; i < n; ++i)
    for (size_t j = i + 1; j < n; ++j)
      result.pairs.push_back(test_pair(marks[i], marks[j]));
  auto active = [&result](size_t i) {  // few marks are ever out: a search is cheapest
    return std::find(result.excluded.begin(), result.excluded.end(), i) == result.excluded.end();
  };
  std::vector<double>& score = result.mean_z2;
  size_t active_count = n;
  bool first = true;
  while (active_count >= 2) {
    const size_t pairs = active_count * (active_count - 1) / 2;
    const double threshold = pair_threshold(config.false_alarm_probability, pairs);
    if (first) result.pair_threshold_z2 = threshold;
    // Each mark's sum over its active pairs, in the pairs' order (i-major, so each mark's
    // terms come in the order of its partners).
    bool any_fail = false;
    score.assign(n, 0.0);
    size_t k = 0;
    for (size_t i = 0; i < n; ++i) {
      const bool active_i = active(i);
      for (size_t j = i + 1; j < n; ++j, ++k) {
        if (!active_i || !active(j)) continue;
        const double z2 = result.pairs[k].z2;
        if (z2 > threshold) any_fail = true;
        score[i] += z2;
        score[j] += z2;
      }
    }
    size_t worst = n;
    double worst_score = -1;
    for (size_t i = 0; i < n; ++i) {
      if (!active(i)) continue;
      score[i] /= static_cast<double>(active_count - 1);
      if (score[i] > worst_score) {
        worst_score = score[i];
        worst = i;
      }
    }
    if (first) result.failed = any_fail;
    first = false;
    if (!any_fail) {
      result.consistent_after = true;
      return;
    }
    if (static_cast<int>(active_count) <= config.min_marks) {
      result.consistent_after = false;
      return;
    }
    --active_count;
    result.excluded_ids.push_back(marks[worst].id);
    result.excluded.push_back(worst);
  }
}

}  // namespace storetrack::rigid
