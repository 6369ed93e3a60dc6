// Layout check per body: the pose filter's Kalman update (tracked bodies) or an absolute
// orientation fit (estimation/pose; Umeyama, IEEE TPAMI 13(4), 1991) with its chi-square test.
#include "matcher_work.hpp"

#include <algorithm>
#include <cmath>
#include <span>

#include <Eigen/Eigenvalues>

#include "storetrack/camera/camera_model.hpp"
#include "storetrack/pose/body_pose.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"

namespace storetrack::match {

bool layout_well_spread(std::span<const Vec3> q_b, double min_spread) {
  // The singular values are the square roots of the eigenvalues of the 3x3 scatter matrix.
  Vec3 mean = Vec3::Zero();
  for (const Vec3& q : q_b)
    mean += q;
  mean /= static_cast<double>(q_b.size());
  Mat3 scatter = Mat3::Zero();
  for (const Vec3& q : q_b)
    scatter.noalias() += (q - mean) * (q - mean).transpose();
  const Vec3 ev = Eigen::SelfAdjointEigenSolver<Mat3>(scatter, Eigen::EigenvaluesOnly)
                      .eigenvalues();  // ascending
  return ev[1] > min_spread * min_spread * ev[2];
}

bool layout_well_posed(std::span<const Vec3> q_b, const Mat6& cov, const MatcherConfig& config) {
  if (!layout_well_spread(q_b, config.min_layout_spread)) return false;
  const double rot_var = cov.topLeftCorner<3, 3>().diagonal().maxCoeff();
  const double trans_var = cov.bottomRightCorner<3, 3>().diagonal().maxCoeff();
  return cov.allFinite() && std::sqrt(rot_var) <= config.max_layout_rotation_sigma_rad &&
         std::sqrt(trans_var) <= config.max_layout_translation_sigma_m;
}

bool fit_layout(pose::PointsInBody q_body, pose::PointsInWorld p_world, std::span<const Mat3> cov_w,
                std::vector<double>& weights_scratch, LayoutFit& out) {
  const std::span<const Vec3> q_b = q_body.points, p_w = p_world.points;
  const size_t n = q_b.size();
  weights_scratch.assign(n, 1.0);
  if (!pose::absolute_orientation(q_body, p_world, weights_scratch, out.T_w_b)) return false;
  Mat6 info = Mat6::Zero();
  out.chi2 = 0;
  for (size_t i = 0; i < n; ++i) {
    Mat3 W;
    if (!uncertainty::inverse_spd<3>(cov_w[i], W)) return false;
    const Vec3 e = p_w[i] - out.T_w_b * q_b[i];
    out.chi2 += e.dot(W * e);
    const auto G = point_pose_jacobian(out.T_w_b, q_b[i]);
    info += G.transpose() * W * G;
  }
  return uncertainty::inverse_spd<6>(info, out.cov);
}

bool fit_body_pose(const survey::RigidBodySurvey& body, const std::map<int, Vec3>& p_w_by_id,
                   double sigma_m, Transform& T_w_b, Mat6& covariance) {
  std::vector<const survey::SurveyedMark*> used;
  std::vector<Vec3> p_w;
  for (const auto& m : body.marks)
    if (const auto it = p_w_by_id.find(m.id); it != p_w_by_id.end()) {
      used.push_back(&m);
      p_w.push_back(it->second);
    }
  const int n = static_cast<int>(used.size());
  if (n < 3) return false;
  std::vector<Vec3> q_b(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i)
    q_b[static_cast<size_t>(i)] = used[i]->p_body;
  if (!layout_well_spread(q_b, 0.1)) return false;  // collinear: rotation about the line undefined
  const std::vector<double> equal_weights(static_cast<size_t>(n), 1.0);
  if (!pose::absolute_orientation(pose::PointsInBody{q_b}, pose::PointsInWorld{p_w}, equal_weights,
                                  T_w_b))
    return false;
  Mat6 info = Mat6::Zero();
  for (int i = 0; i < n; ++i) {
    const double var = sigma_m * sigma_m + used[i]->sigma_m * used[i]->sigma_m;
    const auto G = point_pose_jacobian(T_w_b, used[i]->p_body);
    info += G.transpose() * G / var;
  }
  return uncertainty::inverse_spd<6>(info, covariance);
}

bool MarkMatcher::single_view_measurement(const Work& w, int m, const Transform& T_w_b, Vec2& y,
                                          Eigen::Matrix<double, 2, 6>& H, Mat2& W) const {
  // The observed pixel against the projection of the surveyed mark through the pose; its noise:
  // the centroid's sigma (with quantisation), the calibration pixel covariance (from gating)
  // and the survey sigma through the projection.
  const Work::Obs& ob = w.obs[w.assigned[m].front()];
  camera::ProjectionJacobians J;
  const auto px =
      camera::project_body_point(rig_.cameras[ob.slot], T_w_b, marks_[m].p_body, &H, &J);
  if (!px) return false;
  y = ob.raw - *px;
  const double s = marks_[m].survey_sigma_m;
  const Mat2 R = ob.S_cal + ob.sigma * ob.sigma * Mat2::Identity() +
                 s * s * J.d_point_world * J.d_point_world.transpose();
  return uncertainty::inverse_spd<2>(R, W);
}

int MarkMatcher::measurement_dof(const Work& w, const std::vector<int>& members) {
  int dof = 0;
  for (int m : members)
    dof += w.tri[m].valid ? 3 : 2;
  return dof;
}

bool MarkMatcher::filter_update(Work& w, int b, const std::vector<int>& members, PoseFilter& post,
                                double& nis) const {
  // Extended Kalman filter update (Bar-Shalom et al. 2001, sec. 5.2 and 10.3). The marks
  // measure the pose only, so the pose is updated in information form on its 6x6 block,
  // Info = Ppp^-1 + sum H^T W H, with one relinearisation (iterated EKF, sec. 10.3.2), and the
  // rates follow through their correlation with the pose (L = Prp Ppp^-1, exact for a
  // measurement of a sub-state). The normalised innovation squared
  // y^T (H Ppp H^T + R)^-1 y = y^T W y - g^T Info^-1 g (matrix inversion lemma) at the prediction.
  // A triangulated mark measures its 3-D position (H = G); a mark seen by one camera measures
  // its pixel, the projection of its surveyed point (single_view_measurement).
  const PoseFilter& pred = w.body[b].pred;
  const Mat6 Ppp = pred.P.topLeftCorner<6, 6>();
  Mat6 Ppp_inv;
  if (!uncertainty::inverse_spd<6>(Ppp, Ppp_inv)) return false;
  // The triangulated marks' weights do not change between the iterations.
  std::vector<Mat3>& W_point = w.filter_point_weights;
  W_point.resize(members.size());
  for (size_t k = 0; k < members.size(); ++k) {
    const int m = members[k];
    if (!w.tri[m].valid) continue;
    const double s = marks_[m].survey_sigma_m;
    if (!uncertainty::inverse_spd<3>(Mat3(w.tri[m].cov + s * s * Mat3::Identity()), W_point[k]))
      return false;
  }
  geometry::Vec6 delta = geometry::Vec6::Zero();
  Mat6 info, Ppp_post;
  for (int iter = 0; iter < 2; ++iter) {
    const Transform T = geometry::perturb_left(pred.T_w_b, delta);
    info = Ppp_inv;
    geometry::Vec6 g = -Ppp_inv * delta;
    double yWy = 0;
    for (size_t k = 0; k < members.size(); ++k) {
      const int m = members[k];
      if (!w.tri[m].valid) {
        Vec2 y;
        Eigen::Matrix<double, 2, 6> H;
        Mat2 W;
        if (!single_view_measurement(w, m, T, y, H, W)) return false;
        const Eigen::Matrix<double, 6, 2> HtW = H.transpose() * W;
        info.noalias() += HtW * H;
        g.noalias() += HtW * y;
        yWy += y.dot(W * y);
        continue;
      }
      const Mat3& W = W_point[k];
      const Vec3 y = w.tri[m].p - T * marks_[m].p_body;
      const auto G = point_pose_jacobian(T, marks_[m].p_body);
      const Eigen::Matrix<double, 6, 3> GtW = G.transpose() * W;
      info.noalias() += GtW * G;
      g.noalias() += GtW * y;
      yWy += y.dot(W * y);
    }
    // The last iteration's information is inverted for the posterior; the first only solved.
    geometry::Vec6 step;
    if (iter == 0) {
      if (!uncertainty::solve_spd<6>(info, g, step)) return false;
    } else {
      if (!uncertainty::inverse_spd<6>(info, Ppp_post)) return false;
      step = Ppp_post * g;
    }
    if (!step.allFinite()) return false;
    if (iter == 0) nis = yWy - g.dot(step);
    delta += step;
  }
  const Mat6 L = pred.P.bottomLeftCorner<6, 6>() * Ppp_inv;  // rates | pose gain
  post = pred;
  post.T_w_b = geometry::perturb_left(pred.T_w_b, delta);
  const geometry::Vec6 d_rates = L * delta;
  post.omega_w += d_rates.head<3>();
  post.v_w += d_rates.tail<3>();
  post.P.topLeftCorner<6, 6>() = 0.5 * (Ppp_post + Ppp_post.transpose());
  post.P.bottomLeftCorner<6, 6>() = L * post.P.topLeftCorner<6, 6>();
  post.P.topRightCorner<6, 6>() = post.P.bottomLeftCorner<6, 6>().transpose();
  const Mat6 Prr = pred.P.bottomRightCorner<6, 6>() - L * pred.P.topRightCorner<6, 6>() +
                   L * post.P.topLeftCorner<6, 6>() * L.transpose();
  post.P.bottomRightCorner<6, 6>() = 0.5 * (Prr + Prr.transpose());
  return post.P.allFinite() && std::isfinite(nis);
}

void MarkMatcher::verify_layouts(Work& w) const {
  // Marks whose ids their body's layout does not confirm lose their observations (left for the
  // next gating pass) and leave the body's member list.
  // The layout test failed: when leaving out exactly one member makes it pass (only tried with
  // at least min_members), that member's id is rejected; otherwise the wrong id cannot be told
  // and none of this body's ids is trusted.
  const auto reject_unique_culprit = [&w](std::vector<int>& members, size_t min_members,
                                          const auto& passes_without) {
    int culprit = -1, passing = 0;
    if (members.size() >= min_members) {
      for (size_t k = 0; k < members.size(); ++k) {
        std::vector<int> rest = members;
        rest.erase(rest.begin() + static_cast<long>(k));
        if (passes_without(rest)) {
          ++passing;
          culprit = static_cast<int>(k);
        }
      }
    }
    const std::vector<int> drop =
        passing == 1 ? std::vector<int>{members[static_cast<size_t>(culprit)]} : members;
    for (int m : drop) {
      w.unassign_mark(m, ObsState::kUngated);
      ++w.counts.layout_rejected;
      members.erase(std::find(members.begin(), members.end(), m));
    }
  };
  for (int b = 0; b < static_cast<int>(bodies_.size()); ++b) {
    if (w.reacquired[b]) {
      verify_against_reacquired_pose(w, b);
      continue;
    }
    w.fitted[b] = false;
    w.body[b].updated = false;
    std::vector<int>& members = w.layout_members;
    members.clear();
    // Marks identified in one camera only update the body's own filter (not a prior alone:
    // MatcherConfig::single_view_requires_track); their ids are tested with the others.
    const bool single_views = w.body[b].from_track && config_.keep_single_view;
    for (int m = 0; m < static_cast<int>(marks_.size()); ++m)
      if (marks_[m].body == b && (w.tri[m].valid || (single_views && w.assigned[m].size() == 1)))
        members.push_back(m);
    if (w.body[b].predicted) {
      // Tracked body: Kalman update of its pose filter with the triangulated marks; the
      // normalised innovation squared (dof 3n) is the layout test. Works with any number of
      // marks, collinear ones included (the filter carries the unobserved roll).
      while (!members.empty()) {
        PoseFilter post;
        double nis = 0;
        if (filter_update(w, b, members, post, nis) &&
            nis <= chi2_gate_[std::min(kMaxDof, measurement_dof(w, members))]) {
          w.body[b].updated = true;
          w.body[b].post = post;
          w.fitted[b] = true;
          w.T_w_b[b] = post.T_w_b;
          w.cov_b[b] = post.P.topLeftCorner<6, 6>();
          break;
        }
        reject_unique_culprit(members, 2, [&](const std::vector<int>& rest) {
          PoseFilter post_rest;
          double nis_rest = 0;
          return filter_update(w, b, rest, post_rest, nis_rest) &&
                 nis_rest <= chi2_gate_[std::min(kMaxDof, measurement_dof(w, rest))];
        });
      }
      continue;
    }
    // Fit and test (triangulated marks only); on failure remove the unique culprit (>= 4 marks)
    // and try again.
    std::erase_if(members, [&w](int m) { return !w.tri[m].valid; });
    while (static_cast<int>(members.size()) >= std::max(3, config_.min_layout_marks)) {
      // Fit (false: no pose or no covariance, i.e. nothing to test) and chi-square test.
      auto fit = [&](const std::vector<int>& set, Transform& T, Mat6& cov, bool& consistent) {
        const int n = static_cast<int>(set.size());
        auto &q_b = w.layout_q_b, &p_w = w.layout_p_w;
        auto& cov_w = w.layout_cov;
        q_b.resize(set.size());
        p_w.resize(set.size());
        cov_w.resize(set.size());
        for (int i = 0; i < n; ++i) {
          const double s = marks_[set[i]].survey_sigma_m;
          q_b[i] = marks_[set[i]].p_body;
          p_w[i] = w.tri[set[i]].p;
          cov_w[i] = w.tri[set[i]].cov + s * s * Mat3::Identity();
        }
        LayoutFit lf;
        if (!fit_layout(pose::PointsInBody{q_b}, pose::PointsInWorld{p_w}, cov_w, w.layout_weights,
                        lf))
          return false;
        T = lf.T_w_b;
        cov = lf.cov;
        consistent = lf.chi2 <= chi2_gate_[3 * n - 6];
        return true;
      };
      // A layout whose marks are (nearly) collinear leaves the rotation about that line
      // undetermined: absolute orientation then returns an arbitrary roll that passes the
      // chi-square test. Such a fit neither verifies ids nor predicts the other marks.
      auto well_posed = [&](const std::vector<int>& set, const Mat6& cov) {
        auto& q_b = w.layout_q_b;
        q_b.resize(set.size());
        for (size_t i = 0; i < set.size(); ++i)
          q_b[i] = marks_[set[i]].p_body;
        return layout_well_posed(q_b, cov, config_);
      };
      Transform T;
      Mat6 cov;
      bool consistent = false;
      // Cannot check: ids rest on their predictions.
      if (!fit(members, T, cov, consistent) || !well_posed(members, cov)) break;
      if (consistent) {
        w.fitted[b] = true;
        w.T_w_b[b] = T;
        w.cov_b[b] = cov;
        break;
      }
      reject_unique_culprit(members, 4, [&](const std::vector<int>& rest) {
        Transform T2;
        Mat6 cov2;
        bool consistent2 = false;
        return fit(rest, T2, cov2, consistent2) && consistent2 && well_posed(rest, cov2);
      });
    }
    // Unverifiable single-view or untriangulated assignments of an unfitted body stay as they
    // are (their ids rest on the prediction alone, see MatcherConfig::single_view_*).
  }
}

void MarkMatcher::verify_against_reacquired_pose(Work& w, int b) const {
  // A body re-acquired in this exposure keeps the search's verified pose; each triangulated
  // mark the bootstrap assigned is tested on its own against that pose (chi-square(3) of
  // p - T q with G P G^T + triangulation + survey covariance), so bad marks (e.g. a two-view
  // point off its mark) are dropped one by one instead of failing the whole layout.
  for (int m = 0; m < static_cast<int>(marks_.size()); ++m) {
    if (marks_[m].body != b || !w.tri[m].valid) continue;
    const double s = marks_[m].survey_sigma_m;
    const Mat3 C = point_covariance(w.T_w_b[b], marks_[m].p_body, w.cov_b[b]) + w.tri[m].cov +
                   s * s * Mat3::Identity();
    const Vec3 e = w.tri[m].p - w.T_w_b[b] * marks_[m].p_body;
    Mat3 W;
    if (uncertainty::inverse_spd<3>(C, W) && e.dot(W * e) <= chi2_gate_[3]) continue;
    w.unassign_mark(m, ObsState::kUngated);
    ++w.counts.layout_rejected;
  }
}

}  // namespace storetrack::match
