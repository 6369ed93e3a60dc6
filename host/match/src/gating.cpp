// Chi-square gates of predicted marks against each camera's observations (Bar-Shalom et al.
// 2001, sec. 5.4) with the calibration pixel covariance, and unique assignment.
#include "matcher_work.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "storetrack/uncertainty/calibration_factors.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"

namespace storetrack::match {

void MarkMatcher::compute_calibration_bounds() {
  // Upper bound on trace(S_cal) (pixel covariance from the calibration covariance) over the
  // image (plus margin) as a + b / z^2 for a point at depth z: with p_cam = z (x, y, 1) the
  // intrinsic and rotation parts do not depend on z, the translation part scales with 1/z, and
  // (u + v)^T C (u + v) <= 2 u^T C u + 2 v^T C v. Evaluated on a grid, x 1.5 between nodes.
  cal_bounds_.assign(rig_.cameras.size(), {});
  for (size_t slot = 0; slot < rig_.cameras.size(); ++slot) {
    const auto& cal = rig_.cameras[slot];
    const auto& in = cal.model.intrinsics();
    const double margin = config_.image_margin_px + 0.5;
    constexpr int kGrid = 12;
    double a = 0, b = 0, min_scale = std::numeric_limits<double>::infinity();
    for (int iu = 0; iu <= kGrid; ++iu)
      for (int iv = 0; iv <= kGrid; ++iv) {
        const Vec2 px(-margin + (in.width + 2 * margin) * iu / kGrid,
                      -margin + (in.height + 2 * margin) * iv / kGrid);
        const auto xy = cal.model.unproject(px, 1e-6, 50);
        if (!xy) continue;
        const Vec3 p_cam(xy->x(), xy->y(), 1.0);
        Eigen::Matrix<double, 2, 3> J_cam;
        Eigen::Matrix<double, 2, camera::kNumIntrinsics> J_int;
        if (!cal.model.project(p_cam, &J_cam, &J_int)) continue;
        // Smallest singular value: sqrt of the smaller eigenvalue of A^T A (2x2, closed form).
        const Mat2 AtA = J_cam.leftCols<2>().transpose() * J_cam.leftCols<2>();
        const double half_trace = AtA.trace() / 2;
        const double lambda_min =
            half_trace - std::sqrt(std::max(0.0, half_trace * half_trace - AtA.determinant()));
        min_scale = std::min(min_scale, std::sqrt(std::max(0.0, lambda_min)));
        if (!config_.use_calibration_covariance) continue;
        const Eigen::Matrix<double, 2, 3> J_rot = -J_cam * geometry::skew(p_cam);
        const Mat3 C_rot = cal.extrinsic_covariance.topLeftCorner<3, 3>();
        const Mat3 C_trans = cal.extrinsic_covariance.bottomRightCorner<3, 3>();
        const double t_int = (J_int * cal.intrinsic_covariance * J_int.transpose()).trace();
        const double t_rot = (J_rot * C_rot * J_rot.transpose()).trace();
        const double t_trans = (J_cam * C_trans * J_cam.transpose()).trace();
        a = std::max(a, t_int + 2 * t_rot);
        b = std::max(b, 2 * t_trans);
      }
    // Independent intrinsic and extrinsic errors add: trace(A + B) = trace A + trace B.
    // Correlated (a joint covariance's cross term), the same inequality again: x 2.
    const double coupling = factors_.intrinsic_extrinsic_correlated(static_cast<int>(slot)) ? 2 : 1;
    // The pixel scale varies smoothly (distortion): / 1.5 between grid nodes as well.
    cal_bounds_[slot] = {1.5 * coupling * a, 1.5 * coupling * b, min_scale / 1.5};
  }
}

void MarkMatcher::gate_and_assign(Work& w) const {
  const double gate = chi2_gate_[2];
  for (int c = 0; c < static_cast<int>(w.cams.size()); ++c) {
    const Work::Cam& cam = w.cams[c];
    const camera::CalibratedCamera& cal = rig_.cameras[cam.slot];
    const camera::Intrinsics& in = cal.model.intrinsics();
    const Mat3 R_c_w = cal.T_c_w.linear();
    const Vec3 t_c_w = cal.T_c_w.translation();
    // This camera's free observations and their largest variance (for the pixel pre-gate).
    auto& free_obs = w.free_obs;
    free_obs.clear();
    double max_var = 0;
    for (int o : cam.obs)
      if (w.obs[o].state != ObsState::kAssigned) {
        free_obs.push_back(o);
        max_var = std::max(max_var, w.obs[o].sigma * w.obs[o].sigma);
      }
    // Candidate marks: predicted and not yet assigned in this camera. The second (layout) pass
    // re-gates every remaining mark, so an observation a tight layout prediction claims is
    // still ambiguous when a coarse prediction of another mark also covers it.
    auto& cand = w.cand;
    cand.clear();
    for (int m = 0; m < static_cast<int>(marks_.size()); ++m) {
      const auto& pr = w.pred[m];
      if (!pr.valid) continue;
      bool already = false;
      for (int o : w.assigned[m])
        already = already || w.obs[o].cam == c;
      if (already) continue;
      const Vec3 p_cam = R_c_w * pr.p + t_c_w;
      Eigen::Matrix<double, 2, 3> J_cam;
      const auto px = cal.model.project(p_cam, &J_cam);
      if (!px) continue;
      const double margin = config_.image_margin_px;
      if (px->x() < -0.5 - margin || px->x() > in.width - 0.5 + margin || px->y() < -0.5 - margin ||
          px->y() > in.height - 0.5 + margin)
        continue;
      Work::Cand cd;
      cd.mark = m;
      cd.px = *px;
      cd.J_w = J_cam * R_c_w;
      cd.p_w = pr.p;
      cd.z = p_cam.z();
      cd.S_pred = cd.J_w * pr.cov * cd.J_w.transpose();
      // Pre-gate radius: lambda_max(S) <= trace(S_pred) + bound on trace(S_cal) + max sigma^2,
      // and d^T S^-1 d >= |d|^2 / lambda_max(S); pairs further apart cannot be in the gate.
      cd.radius2 = gate * (cd.S_pred.trace() + calibration_bound(cam.slot, p_cam.z()) + max_var);
      cand.push_back(cd);
    }
    const int M = static_cast<int>(cand.size()), N = static_cast<int>(free_obs.size());
    auto& mark_hits = w.mark_hits;
    auto& mark_hit = w.mark_hit;
    auto& obs_hits = w.obs_hits;
    auto& obs_hit = w.obs_hit;
    mark_hits.assign(M, 0);
    mark_hit.assign(M, -1);
    obs_hits.assign(N, 0);
    obs_hit.assign(N, -1);
    // Each mark meets only the observations within its pre-gate radius in x: a binary search
    // in the observations sorted by column instead of all M x N pairs. The assignment below
    // depends on the hit counts only, not on the order in which the pairs are visited.
    auto& by_x = w.free_by_x;
    by_x.clear();
    for (int k = 0; k < N; ++k)
      by_x.emplace_back(w.obs[free_obs[k]].raw.x(), k);
    std::sort(by_x.begin(), by_x.end());
    for (int i = 0; i < M; ++i) {
      Work::Cand& cd = cand[i];
      const double reach = std::sqrt(cd.radius2);
      auto it = std::lower_bound(by_x.begin(), by_x.end(), std::pair{cd.px.x() - reach, -1});
      for (; it != by_x.end() && it->first <= cd.px.x() + reach; ++it) {
        const int k = it->second;
        const auto& ob = w.obs[free_obs[k]];
        const Vec2 d = ob.raw - cd.px;
        if (d.squaredNorm() > cd.radius2) continue;
        if (!cd.cal_done) {
          // The calibration part varies slowly over the image and with depth: reuse this mark's
          // value from a previous exposure while its projection stayed within kCacheRadiusPx
          // and its depth within 5 % (cache per mark and camera, invalidated otherwise).
          constexpr double kCacheRadiusPx = 16.0;
          auto& cache = w.cal_cache[static_cast<size_t>(cd.mark) * rig_.cameras.size() +
                                    static_cast<size_t>(cam.slot)];
          if (!(cache.valid && (cache.px - cd.px).squaredNorm() < kCacheRadiusPx * kCacheRadiusPx &&
                std::abs(cd.z / cache.z - 1) < 0.05)) {
            cache.S_cal = calibration_pixel_covariance(cam.slot, cd.p_w);
            cache.px = cd.px;
            cache.z = cd.z;
            cache.valid = true;
          }
          cd.S_cal = cache.S_cal;
          cd.cal_done = true;
        }
        const Mat2 S = cd.S_pred + cd.S_cal + ob.sigma * ob.sigma * Mat2::Identity();
        const double det = S(0, 0) * S(1, 1) - S(0, 1) * S(1, 0);
        if (!(det > 0)) continue;
        const double d2 = (S(1, 1) * d.x() * d.x() - (S(0, 1) + S(1, 0)) * d.x() * d.y() +
                           S(0, 0) * d.y() * d.y()) /
                          det;
        if (!(d2 <= gate)) continue;
        ++mark_hits[i];
        mark_hit[i] = k;
        ++obs_hits[k];
        obs_hit[k] = i;
      }
    }
    for (int k = 0; k < N; ++k) {
      auto& ob = w.obs[free_obs[k]];
      if (obs_hits[k] == 0) {
        ob.state = ObsState::kUngated;
        continue;
      }
      const int i = obs_hit[k];
      if (obs_hits[k] == 1 && mark_hits[i] == 1) {
        // S_cal is positive semidefinite and sigma > 0: the sum is positive definite unless the
        // calibration covariance is corrupt; such an observation is left ungated.
        if (!uncertainty::inverse_spd<2>(
                Mat2(cand[i].S_cal + ob.sigma * ob.sigma * Mat2::Identity()), ob.W)) {
          ob.state = ObsState::kUngated;
          continue;
        }
        ob.state = ObsState::kAssigned;
        ob.mark = cand[i].mark;
        ob.S_cal = cand[i].S_cal;
        ob.start = {cand[i].px, cand[i].J_w};
        ob.start_mark = cand[i].mark;
        ob.start_p_w = cand[i].p_w;
        w.assigned[cand[i].mark].push_back(free_obs[k]);
        w.dirty[cand[i].mark] = true;
      } else {
        ob.state = ObsState::kAmbiguous;
      }
    }
    for (int i = 0; i < M; ++i) {
      const std::uint64_t bit = std::uint64_t{1} << c;
      auto& amb = w.ambiguous_cams[cand[i].mark];
      amb = mark_hits[i] >= 2 ? (amb | bit) : (amb & ~bit);
    }
  }
}

Mat2 MarkMatcher::calibration_pixel_covariance(int slot, const Vec3& p_w) const {
  if (!config_.use_calibration_covariance) return Mat2::Zero();
  const camera::CalibratedCamera& cal = rig_.cameras[slot];
  camera::ProjectionJacobians J;
  if (!cal.model.project_world(cal.T_c_w, p_w, &J)) return Mat2::Zero();
  return uncertainty::pixel_covariance(factors_, slot, J);
}

double MarkMatcher::calibration_bound(int slot, double z_cam) const {
  const auto& bd = cal_bounds_[slot];
  return bd.a + bd.b / (z_cam * z_cam);
}

}  // namespace storetrack::match
