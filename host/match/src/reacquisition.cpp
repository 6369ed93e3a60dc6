// Re-acquisition of a body without a usable prediction (docs/matching.md, step 6): its track
// timed out, its extrapolated gates grew wider than its mark spacing, or its prior pose explains
// none of the observations (host started after the release).
//
// 1. Candidate points: free observations (no id, or an unconfirmed id of this body) are paired
//    across cameras; a pair is kept when estimation/triangulate's two-view reprojection chi-square
//    (the epipolar constraint with its uncertainty) passes chi-square(1); each pair is extended by
//    the one observation per other camera consistent with both, and the set is triangulated again
//    with the calibration pixel covariance at the point (chi-square(2n - 3)).
// 2. Layout hypotheses (alignment / interpretation tree, Grimson & Lozano-Perez 1987): every
//    well-spread triple of candidates whose three distances match three surveyed distances, the
//    gate from the triangulation covariance along the line and the survey sigmas (chi-square(1)),
//    gives a pose (estimation/pose's absolute orientation); the pose predicts every mark and takes
//    the candidates uniquely inside its chi-square(3) gate; refit, extend once more, refit.
// 3. A hypothesis passes with >= min_reacquisition_marks well-spread marks (min_layout_spread,
//    max_layout_*_sigma) and the fit's chi-square(3n - 6). Hypotheses outside the body's region
//    (set_region) are excluded; plausible hypotheses, well posed or not, with the same pose
//    (chi-square(6) of their difference) and well-posedness are one interpretation; an
//    interpretation whose observations explained before the trim are a strict subset of another's
//    fitted ones is dropped (it leaves points unexplained that the other explains with the same
//    layout). Exactly one interpretation left, well posed: accepted, the body's filter starts
//    from its pose and the bootstrap step assigns the marks. Otherwise: refused (ambiguous).
#include "matcher_work.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iterator>
#include <optional>

#include "storetrack/uncertainty/spd_inverse.hpp"

namespace storetrack::match {

enum class MarkMatcher::SearchOutcome : std::uint8_t {
  kAccepted,
  kAmbiguous,
  kInconsistent,
  kTooFewMarks,
  kOutsideRegion,
};

namespace {

std::vector<int> sorted_union(const std::vector<int>& a, const std::vector<int>& b) {
  std::vector<int> u;
  std::set_union(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(u));
  return u;
}

bool shares_observation(const std::vector<int>& a, const std::vector<int>& b) {
  for (int o : a)
    if (std::binary_search(b.begin(), b.end(), o)) return true;
  return false;
}

/// Bound on the layout hypotheses tried per search; past it the search is refused as ambiguous
/// (it could not be exhausted).
constexpr int kMaxBases = 20000;

/// One body's surveyed marks as the search sees them.
struct BodyMarks {
  std::vector<int> index;  ///< in MarkMatcher::marks_
  std::vector<Vec3> q_b;
  std::vector<double> sigma_m;
  int size() const { return static_cast<int>(index.size()); }
};

/// Layout hypotheses of one body among the candidate points (steps 2 and 3 of the header).
class LayoutSearch {
 public:
  LayoutSearch(const std::vector<CandidatePoint>& cands, const BodyMarks& marks,
               const std::vector<double>& chi2_gate, const std::vector<double>& competitor_gate,
               const MatcherConfig& config, int min_marks, std::vector<LayoutHypothesis>& hyps)
      : cands_(cands),
        marks_(marks),
        gate_(chi2_gate),
        competitor_gate_(competitor_gate),
        config_(config),
        min_marks_(min_marks),
        hyps_(hyps),
        K_(static_cast<int>(cands.size())),
        M_(marks.size()) {}

  /// Tries every basis; false when kMaxBases was reached (not exhausted).
  bool run();

 private:
  void build_distance_table();
  bool distance_matches(int a, int c, int i, int j) const {
    return table_[(static_cast<size_t>(a) * K_ + c) * M_ * M_ + static_cast<size_t>(i) * M_ + j] !=
           0;
  }
  bool covered(int a, int i, int c, int j, int e, int k) const;
  void try_basis(int a, int c, int e, int i, int j, int k);
  void extend(const Transform& T_w_b, const Mat6& cov, std::vector<std::pair<int, int>>& pairs);
  bool fit(const std::vector<std::pair<int, int>>& pairs, LayoutFit& out);
  void trim(LayoutHypothesis& h);
  void classify(LayoutHypothesis& h);
  std::vector<int> multi_view_observations(const std::vector<std::pair<int, int>>& pairs) const;
  void record(LayoutHypothesis h);

  const std::vector<CandidatePoint>& cands_;
  const BodyMarks& marks_;
  const std::vector<double>& gate_;
  const std::vector<double>& competitor_gate_;
  const MatcherConfig& config_;
  const int min_marks_;
  std::vector<LayoutHypothesis>& hyps_;
  const int K_, M_;
  std::vector<std::uint8_t> table_;             ///< per ordered candidate pair x ordered mark pair
  std::vector<std::vector<int>> hyps_with_;     ///< per (candidate, mark slot): hypotheses
  std::vector<std::vector<int>> cand_of_mark_;  ///< per hypothesis: mark slot -> candidate
  std::vector<Vec3> q_, p_;
  std::vector<Mat3> cov_;
  std::vector<double> weights_;
  std::vector<int> hits_of_cand_;
  std::vector<std::pair<int, int>> found_;
};

void LayoutSearch::build_distance_table() {
  // Distance gate: (d - D)^2 <= chi2(1) (u^T (C_a + C_c) u + s_i^2 + s_j^2), u along the line.
  table_.assign(static_cast<size_t>(K_) * K_ * M_ * M_, 0);
  for (int a = 0; a < K_; ++a)
    for (int c = a + 1; c < K_; ++c) {
      const Vec3 d = cands_[c].p - cands_[a].p;
      const double dist = d.norm();
      const Vec3 u = d / dist;
      const double var_points = u.dot((cands_[a].cov + cands_[c].cov) * u);
      std::uint8_t* ac = &table_[(static_cast<size_t>(a) * K_ + c) * M_ * M_];
      std::uint8_t* ca = &table_[(static_cast<size_t>(c) * K_ + a) * M_ * M_];
      for (int i = 0; i < M_; ++i)
        for (int j = 0; j < M_; ++j) {
          if (i == j) continue;
          const double D = (marks_.q_b[i] - marks_.q_b[j]).norm();
          const double var = var_points + marks_.sigma_m[i] * marks_.sigma_m[i] +
                             marks_.sigma_m[j] * marks_.sigma_m[j];
          const std::uint8_t ok = (dist - D) * (dist - D) <= gate_[1] * var;
          ac[i * M_ + j] = ok;
          ca[j * M_ + i] = ok;
        }
    }
}

bool LayoutSearch::covered(int a, int i, int c, int j, int e, int k) const {
  // A basis all of whose three pairs one hypothesis already holds would only find it again.
  for (int h : hyps_with_[static_cast<size_t>(a) * M_ + i])
    if (cand_of_mark_[h][j] == c && cand_of_mark_[h][k] == e) return true;
  return false;
}

bool LayoutSearch::run() {
  build_distance_table();
  hyps_.clear();
  hyps_with_.assign(static_cast<size_t>(K_) * M_, {});
  cand_of_mark_.clear();
  // Candidates with more views first: real marks are usually seen by >= 3 cameras, so the
  // large hypotheses are found early and cover (skip) most later bases.
  std::vector<int> order(K_);
  for (int k = 0; k < K_; ++k)
    order[k] = k;
  std::stable_sort(order.begin(), order.end(),
                   [&](int x, int y) { return cands_[x].views > cands_[y].views; });
  int bases = 0;
  std::vector<Vec3> corners(3);
  for (int ia = 0; ia < K_; ++ia)
    for (int ic = ia + 1; ic < K_; ++ic) {
      const int a = order[ia], c = order[ic];
      if (shares_observation(cands_[a].obs, cands_[c].obs)) continue;
      for (int ie = ic + 1; ie < K_; ++ie) {
        const int e = order[ie];
        if (shares_observation(cands_[a].obs, cands_[e].obs) ||
            shares_observation(cands_[c].obs, cands_[e].obs))
          continue;
        corners = {cands_[a].p, cands_[c].p, cands_[e].p};
        if (!layout_well_spread(corners, config_.min_layout_spread)) continue;
        for (int i = 0; i < M_; ++i)
          for (int j = 0; j < M_; ++j) {
            if (!distance_matches(a, c, i, j)) continue;
            for (int k = 0; k < M_; ++k) {
              if (!distance_matches(a, e, i, k) || !distance_matches(c, e, j, k) ||
                  covered(a, i, c, j, e, k))
                continue;
              if (++bases > kMaxBases) return false;
              try_basis(a, c, e, i, j, k);
            }
          }
      }
    }
  return true;
}

bool LayoutSearch::fit(const std::vector<std::pair<int, int>>& pairs, LayoutFit& out) {
  q_.clear();
  p_.clear();
  cov_.clear();
  for (const auto& [i, cd] : pairs) {
    q_.push_back(marks_.q_b[i]);
    p_.push_back(cands_[cd].p);
    cov_.push_back(cands_[cd].cov + marks_.sigma_m[i] * marks_.sigma_m[i] * Mat3::Identity());
  }
  return fit_layout(pose::PointsInBody{q_}, pose::PointsInWorld{p_}, cov_, weights_, out);
}

void LayoutSearch::try_basis(int a, int c, int e, int i, int j, int k) {
  // Pose from the basis, then extend and refit twice.
  const std::vector<std::pair<int, int>> basis{{i, a}, {j, c}, {k, e}};
  LayoutFit fit3;
  if (!fit(basis, fit3)) return;
  LayoutHypothesis h;
  LayoutFit current = fit3;
  std::vector<std::pair<int, int>> pairs;
  for (int round = 0; round < 2; ++round) {
    extend(current.T_w_b, current.cov, pairs);
    // Too few marks after the first (widest) extension: no need to refine it.
    if (pairs.size() < 3 || (round == 0 && static_cast<int>(pairs.size()) < min_marks_)) break;
    if (!fit(pairs, current)) break;
    h.pairs = pairs;
    h.fit = current;
  }
  // The basis itself is kept even when the extension lost it (so it is not retried).
  if (h.pairs.empty()) h.pairs = basis;
  if (static_cast<int>(h.pairs.size()) >= min_marks_) {
    const std::vector<int> explained = multi_view_observations(h.pairs);
    trim(h);
    classify(h);
    h.explained = explained;
  }
  record(std::move(h));
}

void LayoutSearch::trim(LayoutHypothesis& h) {
  // A point the extension took that does not belong (e.g. a false two-view correspondence
  // inside a gate) fails the whole hypothesis, which would hide the true interpretation from
  // the ambiguity test: while the test fails, the worst point (largest e^T W e) is dropped.
  auto dof = [&] { return std::min(kMaxDof, 3 * static_cast<int>(h.pairs.size()) - 6); };
  while (static_cast<int>(h.pairs.size()) > min_marks_ && !(h.fit.chi2 <= gate_[dof()])) {
    size_t worst = 0;
    double worst_d2 = -1;
    for (size_t t = 0; t < h.pairs.size(); ++t) {
      const auto [i, cd] = h.pairs[t];
      const Vec3 e = cands_[cd].p - h.fit.T_w_b * marks_.q_b[i];
      Mat3 W;
      const Mat3 C = cands_[cd].cov + marks_.sigma_m[i] * marks_.sigma_m[i] * Mat3::Identity();
      if (!uncertainty::inverse_spd<3>(C, W)) return;
      const double d2 = e.dot(W * e);
      if (d2 > worst_d2) {
        worst_d2 = d2;
        worst = t;
      }
    }
    h.pairs.erase(h.pairs.begin() + static_cast<long>(worst));
    if (!fit(h.pairs, h.fit)) return;
  }
}

void LayoutSearch::classify(LayoutHypothesis& h) {
  const int n = static_cast<int>(h.pairs.size());
  q_.clear();
  for (const auto& [i, cd] : h.pairs)
    q_.push_back(marks_.q_b[i]);
  h.well_posed = layout_well_posed(q_, h.fit.cov, config_);
  const int dof = std::min(kMaxDof, 3 * n - 6);
  h.consistent = h.fit.chi2 <= gate_[dof];
  h.plausible = h.fit.chi2 <= competitor_gate_[dof];
  h.obs = multi_view_observations(h.pairs);
}

std::vector<int> LayoutSearch::multi_view_observations(
    const std::vector<std::pair<int, int>>& pairs) const {
  std::vector<int> obs;
  for (const auto& [i, cd] : pairs)
    if (cands_[cd].views >= 3) obs.insert(obs.end(), cands_[cd].obs.begin(), cands_[cd].obs.end());
  std::sort(obs.begin(), obs.end());
  return obs;
}

void LayoutSearch::record(LayoutHypothesis h) {
  cand_of_mark_.emplace_back(M_, -1);
  for (auto& [i, cd] : h.pairs) {
    cand_of_mark_.back()[i] = cd;
    hyps_with_[static_cast<size_t>(cd) * M_ + i].push_back(static_cast<int>(hyps_.size()));
    i = marks_.index[i];  // stored as MarkMatcher::marks_ indices
  }
  hyps_.push_back(std::move(h));
}

void LayoutSearch::extend(const Transform& T_w_b, const Mat6& cov,
                          std::vector<std::pair<int, int>>& pairs) {
  // Every mark of the body predicted from the pose; a candidate is taken when it is the mark's
  // only candidate inside the chi-square(3) gate and the mark is the candidate's only one, and
  // it shares no observation with another taken candidate.
  hits_of_cand_.assign(K_, 0);
  found_.clear();
  for (int i = 0; i < M_; ++i) {
    const Vec3 p = T_w_b * marks_.q_b[i];
    const Mat3 C_pred = point_covariance(T_w_b, marks_.q_b[i], cov) +
                        marks_.sigma_m[i] * marks_.sigma_m[i] * Mat3::Identity();
    int hit = -1, hits = 0;
    for (int k = 0; k < K_; ++k) {
      const Vec3 e = cands_[k].p - p;
      // e^T C^-1 e >= |e|^2 / lambda_max(C) >= |e|^2 / trace(C): far candidates skip the inverse.
      const Mat3 C_sum = C_pred + cands_[k].cov;
      if (e.squaredNorm() > gate_[3] * C_sum.trace()) continue;
      Mat3 W;
      if (!uncertainty::inverse_spd<3>(C_sum, W) || !(e.dot(W * e) <= gate_[3])) continue;
      ++hits;
      hit = k;
      ++hits_of_cand_[k];
    }
    if (hits == 1) found_.emplace_back(i, hit);
  }
  pairs.clear();
  for (const auto& [i, k] : found_) {
    if (hits_of_cand_[k] != 1) continue;
    bool clash = false;
    for (const auto& [i2, k2] : found_)
      clash = clash || (k2 != k && hits_of_cand_[k2] == 1 &&
                        shares_observation(cands_[k].obs, cands_[k2].obs));
    if (!clash) pairs.emplace_back(i, k);
  }
}

}  // namespace

bool MarkMatcher::triangulate_free(Work& w, std::span<const int> obs, const Vec3& initial,
                                   bool calibration_at_point, Vec3& p_w, Mat3& cov_w,
                                   double& chi2) const {
  // Weights: the observation's sigma plus the calibration pixel covariance, either at the point
  // (final) or bounded by the per-camera trace bound (pairing: wider, never rejects a true pair).
  auto& views = w.tri_views;
  views.clear();
  for (int o : obs) {
    const auto& ob = w.obs[o];
    const auto& cal = rig_.cameras[ob.slot];
    Mat2 S = ob.sigma * ob.sigma * Mat2::Identity();
    if (calibration_at_point) {
      S += calibration_pixel_covariance(ob.slot, initial);
    } else {
      const double z = (cal.T_c_w * initial).z();
      S += calibration_bound(ob.slot, z) * Mat2::Identity();
    }
    Mat2 W;
    if (!uncertainty::inverse_spd<2>(S, W)) return false;
    views.push_back(estimator_view(cal, ob.raw, ob.sigma, W));
  }
  triangulate::Options options;
  options.initial_p_w = initial;
  options.calibration_jacobians = false;
  if (!triangulate::triangulate(views, options, w.tri_result)) return false;
  p_w = w.tri_result.p_w;
  cov_w = w.tri_result.cov_weighted;
  chi2 = w.tri_result.chi2;
  return std::isfinite(chi2) && p_w.allFinite();
}

bool MarkMatcher::undistort(Work& w, int o) const {
  Work::Obs& ob = w.obs[o];
  if (ob.undistortion == Undistortion::kNotYet) {
    // 1e-4 px: 40x below the wire quantisation step (1/256 px), fewer iterations than 1e-6.
    const auto xy = rig_.cameras[ob.slot].model.unproject(ob.raw, 1e-4, 30);
    ob.undistortion = xy ? Undistortion::kDone : Undistortion::kFailed;
    if (xy)
      ob.xy = *xy;
    else
      ++w.counts.undistort_failed;
  }
  return ob.undistortion == Undistortion::kDone;
}

void MarkMatcher::find_epipolar_pairs(Work& w) const {
  const int C = static_cast<int>(w.cams.size());
  // Rays of the free observations (world frame): centre and direction.
  auto ray = [&](int o, Vec3& centre, Vec3& dir) {
    const auto& T = rig_.cameras[w.obs[o].slot].T_c_w;
    const Mat3 Rt = T.linear().transpose();
    centre = -Rt * T.translation();
    dir = Rt * Vec3(w.obs[o].xy.x(), w.obs[o].xy.y(), 1.0);
  };
  // Epipolar-consistent pairs: a first-order pre-gate (Sampson distance of the essential matrix
  // x2^T E x1 = 0, Hartley & Zisserman 2004, sec. 11.4.3, with each observation's sigma plus the
  // calibration bound converted to the normalised plane by the camera's smallest pixel scale,
  // i.e. a wider gate, and 4x the chi-square(1) gate for the first-order error), then the
  // two-view triangulation's reprojection chi-square(1) (the epipolar constraint, exact).
  auto& pairs = w.epipolar_pairs;
  auto& compatible = w.compatible;
  pairs.clear();
  compatible.resize(w.obs.size());
  for (auto& v : compatible)
    v.clear();
  auto normalised_var = [&](int o, double z) {
    const auto& ob = w.obs[o];
    const auto& bound = cal_bounds_[ob.slot];
    const double scale = bound.min_pixel_scale;
    return (ob.sigma * ob.sigma + calibration_bound(ob.slot, std::max(z, 1e-3))) / (scale * scale);
  };
  for (int c1 = 0; c1 < C; ++c1)
    for (int c2 = c1 + 1; c2 < C; ++c2) {
      const auto& T1 = rig_.cameras[w.cams[c1].slot].T_c_w;
      const auto& T2 = rig_.cameras[w.cams[c2].slot].T_c_w;
      const Mat3 R21 = T2.linear() * T1.linear().transpose();
      const Vec3 t21 = T2.translation() - R21 * T1.translation();
      const Mat3 E = geometry::skew(t21) * R21;
      for (int o1 : w.free_by_cam[c1]) {
        Vec3 e1, d1;
        ray(o1, e1, d1);
        const Vec3 x1(w.obs[o1].xy.x(), w.obs[o1].xy.y(), 1.0);
        const Vec3 Ex1 = E * x1;
        for (int o2 : w.free_by_cam[c2]) {
          const Vec3 x2(w.obs[o2].xy.x(), w.obs[o2].xy.y(), 1.0);
          const double r = x2.dot(Ex1);
          const Vec3 Etx2 = E.transpose() * x2;
          Vec3 e2, d2;
          ray(o2, e2, d2);
          const auto mid = triangulate::ray_midpoint(e1, d1, e2, d2);
          if (!mid) continue;
          const double z1 = (T1 * *mid).z(), z2 = (T2 * *mid).z();
          const double sampson_var = normalised_var(o1, z1) * Etx2.head<2>().squaredNorm() +
                                     normalised_var(o2, z2) * Ex1.head<2>().squaredNorm();
          if (!(r * r <= 4 * chi2_gate_[1] * sampson_var)) continue;
          Vec3 p;
          Mat3 cov;
          double chi2 = 0;
          const int two[2] = {o1, o2};
          if (!triangulate_free(w, two, *mid, false, p, cov, chi2) || !(chi2 <= chi2_gate_[1]))
            continue;
          pairs.push_back({o1, o2, p});
          compatible[o1].push_back(o2);
          compatible[o2].push_back(o1);
        }
      }
    }
  for (auto& v : compatible)
    std::sort(v.begin(), v.end());
}

void MarkMatcher::form_candidates(Work& w) const {
  find_epipolar_pairs(w);
  auto& cands = w.candidates;
  cands.clear();
  const int C = static_cast<int>(w.cams.size());
  const auto& compatible = w.compatible;
  auto compat = [&](int a, int b) {
    return std::binary_search(compatible[a].begin(), compatible[a].end(), b);
  };
  // Each pair extended by the one observation per other camera consistent with all members
  // (none where two are: that correspondence is not unique), then triangulated with the
  // calibration covariance at the point; a failing extension falls back to the pair itself.
  std::vector<int> set;
  for (const EpipolarPair& pr : w.epipolar_pairs) {
    set = {pr.o1, pr.o2};
    for (int c = 0; c < C; ++c) {
      if (c == w.obs[pr.o1].cam || c == w.obs[pr.o2].cam) continue;
      int found = -1, count = 0;
      for (int o : w.free_by_cam[c]) {
        bool ok = true;
        for (int s : set)
          ok = ok && compat(o, s);
        if (ok) {
          found = o;
          ++count;
        }
      }
      if (count == 1) set.push_back(found);
    }
    std::sort(set.begin(), set.end());
    for (int attempt = 0; attempt < 2; ++attempt) {
      if (attempt == 1) {
        if (set.size() == 2) break;
        set = {std::min(pr.o1, pr.o2), std::max(pr.o1, pr.o2)};
      }
      bool seen = false;
      for (const auto& cd : cands)
        seen = seen || cd.obs == set;
      if (seen) break;
      CandidatePoint cd;
      double chi2 = 0;
      const int n = static_cast<int>(set.size());
      if (triangulate_free(w, set, pr.p, true, cd.p, cd.cov, chi2) &&
          chi2 <= chi2_gate_[2 * n - 3]) {
        cd.obs = set;
        cd.chi2 = chi2;
        cd.views = n;
        cands.push_back(std::move(cd));
        break;
      }
    }
  }
  // An observation is the image of one mark: a two-view point that uses an observation of a
  // point consistent in three or more views is a false correspondence along an epipolar line
  // (one view is much weaker evidence than three), and only multiplies the bases searched.
  std::vector<bool> in_multi_view(w.obs.size(), false);
  for (const auto& cd : cands)
    if (cd.views >= 3)
      for (int o : cd.obs)
        in_multi_view[o] = true;
  std::erase_if(cands, [&](const CandidatePoint& cd) {
    return cd.views == 2 && (in_multi_view[cd.obs[0]] || in_multi_view[cd.obs[1]]);
  });
}

bool MarkMatcher::inside_region(const Work& w, int b, const Transform& T_w_b) const {
  const Region& rg = regions_[b];
  if (!rg.valid) return true;
  const int ref = rg.reference;
  Transform T_w_ref;
  if (w.fitted[ref]) {
    T_w_ref = w.T_w_b[ref];
  } else if (w.body[ref].predicted) {
    T_w_ref = w.body[ref].pred.T_w_b;
  } else if (priors_[ref].valid) {
    T_w_ref = priors_[ref].T_w_b;
  } else {
    return true;  // reference unknown: nothing excluded (ambiguities are then refused)
  }
  const Transform T_ref_b = T_w_ref.inverse() * T_w_b;
  const Transform& nominal = rg.region.T_ref_b_nominal;
  const double angle =
      geometry::rotvec_from_rotation(nominal.linear().transpose() * T_ref_b.linear()).norm();
  const Vec3 offset = T_ref_b.translation() - nominal.translation();
  return angle <= rg.region.max_rotation_rad &&
         (offset.array() >= rg.region.min_offset_m.array()).all() &&
         (offset.array() <= rg.region.max_offset_m.array()).all();
}

MarkMatcher::SearchOutcome MarkMatcher::choose_hypothesis(const Work& w, int b, int& best) const {
  // Competitors: enough marks, within the competitor gate, inside the region, well posed or not.
  // A hypothesis that is not well posed cannot be accepted, but it is still an interpretation
  // of the points: the store's rings are 0.5 m apart and its two middle rows only 0.1 m, so with
  // those rows seen on all four rings the true 8-mark layout is not well spread
  // (min_layout_spread) while the same points shifted by one ring, six of them on three rings,
  // are; left out, the true interpretation could not drop the shifted one (strict subset) and the
  // shifted one was accepted (docs/matching.md, step 6). Competitors with the same pose
  // (chi-square(6) of the difference) and the same well-posedness form one interpretation,
  // represented by its consistent hypothesis with the most marks. (A hypothesis that is not well
  // posed may have a wide covariance: merged into another interpretation it could make that one
  // look larger than it is.)
  const auto& hyps = w.hypotheses;
  bool any_sizable = false, any_consistent = false;
  struct Group {
    int rep;
    bool well_posed;
    std::vector<int> obs, explained;
  };
  std::vector<Group> groups;
  auto better = [&](int h, int than) {
    const auto &x = hyps[h], &y = hyps[than];
    return x.consistent != y.consistent ? x.consistent : x.pairs.size() > y.pairs.size();
  };
  for (int h = 0; h < static_cast<int>(hyps.size()); ++h) {
    const auto& hy = hyps[h];
    if (hy.well_posed) {
      any_sizable = true;
      any_consistent = any_consistent || hy.consistent;
    }
    if (!hy.plausible || !inside_region(w, b, hy.fit.T_w_b)) continue;
    bool merged = false;
    for (auto& g : groups) {
      if (g.well_posed != hy.well_posed) continue;
      const auto& rep = hyps[g.rep];
      Mat6 W;
      const geometry::Vec6 d = geometry::left_difference(hy.fit.T_w_b, rep.fit.T_w_b);
      if (!uncertainty::inverse_spd<6>(Mat6(rep.fit.cov + hy.fit.cov), W) ||
          !(d.dot(W * d) <= chi2_gate_[6]))
        continue;
      g.obs = sorted_union(g.obs, hy.obs);
      g.explained = sorted_union(g.explained, hy.explained);
      if (better(h, g.rep)) g.rep = h;
      merged = true;
      break;
    }
    if (!merged) groups.push_back({h, hy.well_posed, hy.obs, hy.explained});
  }
  if (!any_sizable) return SearchOutcome::kTooFewMarks;
  bool consistent_in_region = false;
  for (const auto& g : groups)
    consistent_in_region = consistent_in_region || (g.well_posed && hyps[g.rep].consistent);
  if (!consistent_in_region)
    return any_consistent ? SearchOutcome::kOutsideRegion : SearchOutcome::kInconsistent;
  // An interpretation whose multi-view (>= 3) observations are a strict subset of another's is
  // dropped: it leaves real points unexplained that the other explains with the same layout.
  // Its observations before the trim count: with the calibration errors common to its marks the
  // true layout's full chi-square can fail and the trim then drops real marks (the 4-view ones
  // first); what is left may be a subset of the layout shifted by one ring, which must not win.
  int kept = 0;
  for (size_t g = 0; g < groups.size(); ++g) {
    bool dominated = false;
    const std::vector<int>& mine = groups[g].explained;
    for (size_t o = 0; o < groups.size() && !dominated; ++o)
      dominated =
          o != g && groups[o].obs.size() > mine.size() &&
          std::includes(groups[o].obs.begin(), groups[o].obs.end(), mine.begin(), mine.end());
    if (!dominated) {
      ++kept;
      best = static_cast<int>(g);
    }
  }
  // The one interpretation left must be well posed to be accepted; one that is not (the larger,
  // possibly true, layout) leaves nothing that can be verified: refused as ambiguous.
  if (kept != 1 || !groups[static_cast<size_t>(best)].well_posed) return SearchOutcome::kAmbiguous;
  best = groups[static_cast<size_t>(best)].rep;
  return hyps[best].consistent ? SearchOutcome::kAccepted : SearchOutcome::kInconsistent;
}

void MarkMatcher::accept_reacquisition(Work& w, int b, int hypothesis) const {
  // This body's unconfirmed ids are released and its pose starts from the fit (no prediction:
  // a new filter starts from it). The bootstrap step then assigns its marks by the per-camera
  // unique gating from this pose (the hypothesis' own point-to-mark pairs are not trusted for
  // that: a point triangulated from two marks nearly on one camera's ray fits either), and
  // tests each against the pose (verify_against_reacquired_pose).
  for (int m = 0; m < static_cast<int>(marks_.size()); ++m) {
    if (marks_[m].body != b) continue;
    w.unassign_mark(m, ObsState::kUnassigned);
    w.dirty[m] = false;
  }
  const LayoutHypothesis& h = w.hypotheses[hypothesis];
  w.fitted[b] = true;
  w.T_w_b[b] = h.fit.T_w_b;
  w.cov_b[b] = h.fit.cov;
  w.body[b].predicted = false;
  w.body[b].updated = false;
  w.reacquired[b] = true;
}

MarkMatcher::SearchOutcome MarkMatcher::search_body(Work& w, int b) const {
  form_candidates(w);
  const int min_marks = std::max({3, config_.min_layout_marks, config_.min_reacquisition_marks});
  BodyMarks body;
  for (int m = 0; m < static_cast<int>(marks_.size()); ++m)
    if (marks_[m].body == b) {
      body.index.push_back(m);
      body.q_b.push_back(marks_[m].p_body);
      body.sigma_m.push_back(marks_[m].survey_sigma_m);
    }
  if (static_cast<int>(w.candidates.size()) < min_marks || body.size() < min_marks)
    return SearchOutcome::kTooFewMarks;
  LayoutSearch search(w.candidates, body, chi2_gate_, chi2_competitor_gate_, config_, min_marks,
                      w.hypotheses);
  if (!search.run()) return SearchOutcome::kAmbiguous;  // not exhausted: cannot tell
  int best = -1;
  const SearchOutcome outcome = choose_hypothesis(w, b, best);
  if (outcome == SearchOutcome::kAccepted) accept_reacquisition(w, b, best);
  return outcome;
}

void MarkMatcher::reacquire_lost_bodies(Work& w, double t_s) const {
  const int min_marks = std::max({3, config_.min_layout_marks, config_.min_reacquisition_marks});
  for (int b = 0; b < static_cast<int>(bodies_.size()); ++b) {
    if (w.fitted[b]) continue;
    // Free observations: without an id, or with an (unconfirmed) id of this body.
    w.free_by_cam.resize(w.cams.size());
    int cams_with = 0, total = 0;
    for (size_t c = 0; c < w.cams.size(); ++c) {
      auto& fr = w.free_by_cam[c];
      fr.clear();
      for (int o : w.cams[c].obs) {
        const auto& ob = w.obs[o];
        if (ob.state != ObsState::kAssigned || marks_[ob.mark].body == b) fr.push_back(o);
      }
      cams_with += !fr.empty();
      total += static_cast<int>(fr.size());
    }
    if (cams_with < 2 || total < 2 * min_marks) continue;
    if (t_s < next_search_s_[b]) {
      ++w.counts.reacquisition_deferred;
      continue;
    }
    // The search forms rays: it needs the normalised points, and leaves out what cannot be
    // undistorted (undistorted here only, not while the search is deferred).
    for (auto& fr : w.free_by_cam)
      std::erase_if(fr, [&](int o) { return !undistort(w, o); });
    ++w.counts.reacquisition_attempted;
    const SearchOutcome outcome = search_body(w, b);
    w.search_refused[b] = outcome != SearchOutcome::kAccepted;
    switch (outcome) {
      case SearchOutcome::kAccepted:
        ++w.counts.reacquisition_accepted;
        break;
      case SearchOutcome::kAmbiguous:
        ++w.counts.reacquisition_ambiguous;
        break;
      case SearchOutcome::kInconsistent:
        ++w.counts.reacquisition_inconsistent;
        break;
      case SearchOutcome::kTooFewMarks:
        ++w.counts.reacquisition_too_few_marks;
        break;
      case SearchOutcome::kOutsideRegion:
        ++w.counts.reacquisition_outside_region;
        break;
    }
  }
}

}  // namespace storetrack::match
