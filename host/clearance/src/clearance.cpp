#include "storetrack/clearance/clearance.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <type_traits>
#include <utility>

#include <Eigen/Eigenvalues>

#include "storetrack/json/text_file.hpp"

namespace storetrack::clearance {

using geometry::Mat6;
using geometry::Vec3;
using geometry::Vec6;

namespace {

/// The contact normal of a pair: from the aircraft's point to the store's, or the aircraft
/// face's normal when they touch (the direction is then the face's, the sign arbitrary).
Vec3 contact_normal(const MeshPair& pair) {
  const ClosestPair& c = pair.closest;
  return c.distance > 0 ? Vec3((c.p_a - c.p_b) / c.distance) : pair.aircraft_face_normal;
}

/// sqrt(J C J^T); NaN (not 0) when the covariance has a NaN.
double standard_uncertainty(const Vec6& J, const Mat6& cov) {
  const double variance = J.dot(cov * J);
  return std::isnan(variance) ? variance : std::sqrt(std::max(0.0, variance));
}

double distance_uncertainty(const MeshPair& pair, const Vec3& t_p_s, const Mat6& cov) {
  return standard_uncertainty(distance_jacobian(pair.closest.p_a, t_p_s, contact_normal(pair)),
                              cov);
}

}  // namespace

ClearanceModel::ClearanceModel(std::vector<Body> bodies) {
  for (Body& b : bodies)
    (b.frame == BodyFrame::kStore ? store_ : aircraft_).push_back({b.name, MeshBvh(b.mesh)});
  if (store_.empty() || aircraft_.empty())
    throw std::invalid_argument("clearance needs at least one store part and one aircraft part");
  previous_.resize(store_.size() * aircraft_.size());
}

ClearanceModel ClearanceModel::load(const std::string& geometry_path,
                                    const std::optional<geometry::Transform>& T_p_w) {
  return load(geometry_path, jsonfile::read_text_file, T_p_w);
}

ClearanceModel ClearanceModel::load(const std::string& geometry_path,
                                    const GeometryFileReader& read,
                                    const std::optional<geometry::Transform>& T_p_w) {
  const GeometryDescription description = parse_geometry(read(geometry_path), geometry_path);
  std::vector<Body> bodies;
  for (const BodyDescription& b : description.bodies)
    bodies.push_back(load_body(b, read, T_p_w));
  return ClearanceModel(std::move(bodies));
}

std::vector<PartClearance> ClearanceModel::evaluate(const geometry::Transform& T_p_s,
                                                    const Mat6& cov_T_p_s) {
  std::vector<PartClearance> out;
  evaluate(T_p_s, cov_T_p_s, out);
  return out;
}

void ClearanceModel::evaluate(const geometry::Transform& T_p_s, const Mat6& cov_T_p_s,
                              std::vector<PartClearance>& out) {
  // lambda_max bounds every pair's variance: J^T C J <= lambda_max |J|^2, |J|^2 <= 1 + r^2;
  // the blocks' bound sqrt(J^T C J) <= u_rotation r + u_translation is often tighter.
  const auto largest_eigenvalue = [](const auto& symmetric) {
    using Matrix = std::decay_t<decltype(symmetric)>;
    return Eigen::SelfAdjointEigenSolver<Matrix>(symmetric, Eigen::EigenvaluesOnly)
        .eigenvalues()
        .maxCoeff();
  };
  CovarianceBounds bounds{std::numeric_limits<double>::quiet_NaN(), 0, 0};
  if (cov_T_p_s.allFinite()) {
    bounds.lambda_max = largest_eigenvalue(Mat6(cov_T_p_s));
    bounds.u_rotation_rad = std::sqrt(
        std::max(0.0, largest_eigenvalue(geometry::Mat3(cov_T_p_s.topLeftCorner<3, 3>()))));
    bounds.u_translation_m = std::sqrt(
        std::max(0.0, largest_eigenvalue(geometry::Mat3(cov_T_p_s.bottomRightCorner<3, 3>()))));
  }
  out.resize(aircraft_.size());
  for (std::size_t i = 0; i < aircraft_.size(); ++i)
    out[i] = evaluate_part(i, T_p_s, cov_T_p_s, bounds);
}

namespace {

double standard_normal_cdf(double z) {
  return 0.5 * std::erfc(-z / std::numbers::sqrt2);
}

/// The b with sum_g P(d_g + u_g N(0,1) < b) = kLowerBoundMiss (bisection; the sum rises with b).
/// `hi` = min_g (d_g - 2 u_g), where the sum is already >= kLowerBoundMiss.
template <typename Features>
double union_lower_bound(const Features& features, double hi) {
  const auto miss = [&](double b) {
    double sum = 0;
    for (const auto& f : features)
      sum += f.u > 0 ? standard_normal_cdf((b - f.distance) / f.u) : (b >= f.distance ? 1.0 : 0.0);
    return sum;
  };
  double u_max = 0;
  for (const auto& f : features)
    u_max = std::max(u_max, f.u);
  // With m features each term is at most miss/m at d_g - k_m u_g, k_m < 2 + sqrt(2 ln m) + 1.
  double lo = hi - (1 + std::sqrt(2 * std::log(static_cast<double>(features.size())))) * u_max;
  if (miss(lo) > kLowerBoundMiss) return lo;  // not reached with finite inputs
  for (int i = 0; i < 60 && hi - lo > 1e-12 * (1 + std::abs(hi)); ++i) {
    const double mid = 0.5 * (lo + hi);
    (miss(mid) > kLowerBoundMiss ? hi : lo) = mid;
  }
  return lo;
}

}  // namespace

// The closest pair over the store parts; then the feature-switch pass (docs/clearance.md):
// every pair that could add to the miss probability of the bound lies within
// d_min - 2 u_min + kCandidateReachSigmas u_bound, u_bound = sqrt(lambda_max (1 + r^2)) with r
// the store part's radius about its origin (J^T C J <= lambda_max |J|^2, |J|^2 <= 1 + r^2);
// the descent takes that reach per store node, with r the node's own lever arm (LeverArmReach).
PartClearance ClearanceModel::evaluate_part(std::size_t aircraft_part,
                                            const geometry::Transform& T_p_s, const Mat6& cov,
                                            const CovarianceBounds& bounds) {
  const Part& part = aircraft_[aircraft_part];
  const Vec3 t = T_p_s.translation();
  MeshPair best;
  best.closest.distance = std::numeric_limits<double>::infinity();
  const Part* best_store = nullptr;
  for (std::size_t k = 0; k < store_.size(); ++k) {
    const Part& s = store_[k];
    const MeshPair pair =
        closest_pair(s.tree, T_p_s, part.tree, previous_[aircraft_part * store_.size() + k]);
    if (pair.closest.distance < best.closest.distance) {
      best = pair;
      best_store = &s;
    }
  }
  PartClearance r;
  r.part = part.name;
  r.store_part = best_store->name;
  r.distance_m = best.closest.distance;
  r.penetration = best.closest.feature == Feature::kPenetration;
  r.feature = best.closest.feature;
  r.p_store_p = best.closest.p_a;
  r.p_aircraft_p = best.closest.p_b;
  r.q_store_s = T_p_s.inverse() * r.p_store_p;
  r.normal_p = contact_normal(best);
  r.store_triangle = best.store_triangle;
  r.aircraft_triangle = best.aircraft_triangle;
  r.u_distance_m = distance_uncertainty(best, t, cov);
  r.lower_bound_m = r.distance_m - kCoverageFactor * r.u_distance_m;
  if (!std::isfinite(r.lower_bound_m)) return r;

  const double single = r.lower_bound_m;
  candidates_.clear();
  const LeverArmReach reach_at{single,
                               kCandidateReachSigmas,
                               bounds.u_translation_m,
                               bounds.u_rotation_rad,
                               bounds.lambda_max,
                               &cov,
                               t};
  for (const Part& s : store_) {
    if (reach_at.at(s.tree.radius()) <= r.distance_m) continue;  // no pair can add to the sum
    pairs_.clear();
    pairs_within(s.tree, T_p_s, part.tree, reach_at, pairs_);
    for (const MeshPair& pair : pairs_) {
      const Vec6 J = distance_jacobian(pair.closest.p_a, t, contact_normal(pair));
      const double u = standard_uncertainty(J, cov);
      // Its term at any b <= the single bound is below Phi(-kCandidateReachSigmas): left out.
      if (pair.closest.distance - kCandidateReachSigmas * u >= single) continue;
      candidates_.push_back({pair.closest.distance, u, J});
    }
  }
  r.candidate_pairs = std::max<int>(1, static_cast<int>(candidates_.size()));
  if (candidates_.size() <= 1) return r;
  // Distinct features: lowest single bound first; a pair joins the first feature whose distance
  // error it follows (correlation >= kSameFeatureCorrelation).
  std::sort(candidates_.begin(), candidates_.end(), [](const Candidate& a, const Candidate& b) {
    return a.distance - kCoverageFactor * a.u < b.distance - kCoverageFactor * b.u;
  });
  features_.clear();
  for (const Candidate& c : candidates_) {
    const Vec6 CJ = cov * c.J;
    const bool same = std::any_of(features_.begin(), features_.end(), [&](const Candidate& f) {
      return c.u > 0 && f.u > 0 && f.J.dot(CJ) >= kSameFeatureCorrelation * f.u * c.u;
    });
    if (!same) features_.push_back(c);
  }
  r.features = static_cast<int>(features_.size());
  const double lowest = features_.front().distance - kCoverageFactor * features_.front().u;
  r.lower_bound_m = features_.size() == 1 ? lowest : union_lower_bound(features_, lowest);
  return r;
}

}  // namespace storetrack::clearance
