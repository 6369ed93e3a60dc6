// Multi-view check: the reprojection chi-square of estimation/triangulate (Hartley & Zisserman,
// "Multiple View Geometry", 2nd ed., ch. 12; for two views the epipolar constraint with its
// uncertainty), with removal of a unique inconsistent view.
#include "matcher_work.hpp"

#include <cmath>

namespace storetrack::match {

bool MarkMatcher::triangulate(Work& w, const std::vector<int>& obs, const Vec3& initial, Vec3& p_w,
                              Mat3& cov_w, double& chi2) const {
  if (obs.size() < 2) return false;
  // estimation/triangulate's Gauss-Newton on the raw-pixel reprojection error, started at the
  // mark's prediction (inside its gate, i.e. close), weighted by each observation's full
  // information (sigma^2 I + calibration part, the latter evaluated at the prediction during
  // gating: it varies negligibly over the gate). Its chi2 is the multi-view consistency statistic.
  auto& views = w.tri_views;
  views.clear();
  for (int o : obs) {
    const auto& ob = w.obs[o];
    const auto& cal = rig_.cameras[ob.slot];
    triangulate::Observation v;
    v.model = &cal.model;
    v.T_c_w = cal.T_c_w;
    v.pixel_px = ob.raw;
    v.sigma_px = ob.sigma;
    v.information_px = ob.W;
    views.push_back(v);
  }
  triangulate::Options options;
  options.initial_p_w = initial;
  options.calibration_jacobians = false;  // the matcher needs the point and its covariance only
  options.max_iterations = 6;
  // Gauss-Newton converges quadratically from inside the gate: after a step s the remaining error
  // is ~ s^2 / depth, so stopping on a 1 mm step leaves ~1 um at >= 1 m depth (marks' sigma is
  // >= 50 um); chi2 and the covariance are then evaluated at the returned point, not
  // extrapolated from the previous one.
  options.step_tolerance_m = 1e-3;
  if (!triangulate::triangulate(views, options, w.tri_result)) return false;
  p_w = w.tri_result.p_w;
  cov_w = w.tri_result.cov_centroid;
  chi2 = w.tri_result.chi2;
  return std::isfinite(chi2);
}

void MarkMatcher::verify_views(Work& w) const {
  for (int m = 0; m < static_cast<int>(marks_.size()); ++m) {
    // Only marks whose assignments changed since they were last verified.
    if (!w.dirty[m]) continue;
    w.dirty[m] = false;
    auto& as = w.assigned[m];
    auto& tri = w.tri[m];
    tri = {};
    if (as.size() < 2) continue;
    Vec3 p;
    Mat3 cov;
    double chi2 = 0;
    const int n = static_cast<int>(as.size());
    const Vec3 initial = w.pred[m].p;
    const bool ok = triangulate(w, as, initial, p, cov, chi2);
    if (ok && chi2 <= chi2_gate_[2 * n - 3]) {
      tri = {true, p, cov, chi2};
      continue;
    }
    // Inconsistent views. With >= 3 views, drop the one observation whose removal makes the
    // rest consistent, if exactly one does; otherwise the mark is not identified at all.
    int culprit = -1, passing = 0;
    Work::Tri best;
    if (n >= 3) {
      for (int k = 0; k < n; ++k) {
        std::vector<int> rest = as;
        rest.erase(rest.begin() + k);
        double c2 = 0;
        if (triangulate(w, rest, initial, p, cov, c2) && c2 <= chi2_gate_[2 * (n - 1) - 3]) {
          ++passing;
          culprit = k;
          best = {true, p, cov, c2};
        }
      }
    }
    if (passing == 1) {
      auto& ob = w.obs[as[culprit]];
      ob.state = ObsState::kUngated;
      ob.mark = -1;
      as.erase(as.begin() + culprit);
      tri = best;
      ++w.counts.epipolar_outlier;
    } else {
      for (int o : as) {
        w.obs[o].state = ObsState::kUngated;
        w.obs[o].mark = -1;
      }
      as.clear();
      ++w.counts.epipolar_rejected;
    }
  }
}

}  // namespace storetrack::match
