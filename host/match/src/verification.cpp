// Multi-view check: the reprojection chi-square of estimation/triangulate (Hartley & Zisserman,
// "Multiple View Geometry", 2nd ed., ch. 12; for two views the epipolar constraint with its
// uncertainty), with removal of a unique inconsistent view.
#include "matcher_work.hpp"

#include <algorithm>
#include <cmath>

namespace storetrack::match {

bool MarkMatcher::triangulate(Work& w, int m, std::span<const int> obs, const Vec3& initial) const {
  if (obs.size() < 2) return false;
  // estimation/triangulate's Gauss-Newton on the raw-pixel reprojection error, started at the
  // mark's prediction (inside its gate, i.e. close), weighted by each observation's full
  // information (sigma^2 I + calibration part, evaluated at the prediction during gating: it
  // varies negligibly over the gate), each view corrected for the mark's motion between the
  // reference time and its camera's exposure. Its chi2 is the multi-view consistency statistic;
  // the same solution, with its calibration Jacobians and gains, is the mark's estimate.
  const Vec3* velocity_w = m >= 0 && w.motion[m].valid ? &w.motion[m].v_w : nullptr;
  auto& views = w.tri_views;
  views.clear();
  for (int o : obs) {
    const auto& ob = w.obs[o];
    views.push_back(estimator_view(rig_.cameras[ob.slot], ob.raw, ob.sigma, ob.W, velocity_w,
                                   w.cams[ob.cam].dt_s));
    // The gate projected this prediction into the camera already: the first pass reuses it.
    if (ob.start_mark == m && ob.start_p_w == initial) views.back().start = &ob.start;
  }
  if (!triangulate::triangulate(views, estimator_options(initial), w.tri_result)) return false;
  return std::isfinite(w.tri_result.chi2);
}

void MarkMatcher::verify_views(Work& w) const {
  for (int m = 0; m < static_cast<int>(marks_.size()); ++m) {
    // Only marks whose assignments changed since they were last verified.
    if (!w.dirty[m]) continue;
    w.dirty[m] = false;
    auto& as = w.assigned[m];
    std::sort(as.begin(), as.end());  // camera order: the estimate's views are in it
    auto& tri = w.tri[m];
    tri.reject();
    if (as.size() < 2) continue;
    const int n = static_cast<int>(as.size());
    const Vec3 initial = w.pred[m].p;
    if (triangulate(w, m, as, initial) && w.tri_result.chi2 <= chi2_gate_[2 * n - 3]) {
      tri.accept(w.tri_result);
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
        if (triangulate(w, m, rest, initial) && w.tri_result.chi2 <= chi2_gate_[2 * (n - 1) - 3]) {
          ++passing;
          culprit = k;
          best.accept(w.tri_result);
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
