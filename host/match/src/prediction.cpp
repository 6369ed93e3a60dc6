// Prediction of every mark at the exposure time: from its own track, its body's pose filter
// (Bar-Shalom et al. 2001, sec. 6.3.3) or the prior pose (acquisition).
#include "matcher_work.hpp"

#include <Eigen/Eigenvalues>

#include "storetrack/geometry/transform.hpp"

namespace storetrack::match {

void MarkMatcher::predict(Work& w, double t_s) const {
  const double floor2 = config_.min_prediction_sigma_m * config_.min_prediction_sigma_m;
  // Body poses first: the constant-velocity pose filter extrapolated to t_s (Bar-Shalom et
  // al. 2001, sec. 6.3.3, discrete white-noise acceleration, per axis for translation and
  // rotation), else the prior pose (acquisition).
  std::vector<Transform> body_T(bodies_.size());
  std::vector<Mat6> body_cov(bodies_.size());
  std::vector<PredictionSource> body_src(bodies_.size(), PredictionSource::kNone);
  w.body.assign(bodies_.size(), {});
  for (size_t b = 0; b < bodies_.size(); ++b) {
    const PoseFilter& filter = motion_[b].filter;
    const double dt = t_s - filter.t_s;
    if (filter.valid && dt >= 0 && dt <= config_.body_track_max_gap_s) {
      w.body[b].predicted = true;
      w.body[b].from_track = true;
      w.body[b].pred = filter.predicted(t_s, config_.max_angular_acceleration_radps2,
                                        config_.max_acceleration_mps2);
      body_T[b] = w.body[b].pred.T_w_b;
      body_cov[b] = w.body[b].pred.P.topLeftCorner<6, 6>();
      body_src[b] = PredictionSource::kBodyTrack;
    } else if (priors_[b].valid) {
      // Acquisition: the prior pose is the filter's prediction (at rest, rates with their
      // a-priori spread), so even one or two marks, or a collinear row, start the track; the
      // innovation test then checks the marks against the prior and the survey together.
      w.body[b].predicted = true;
      w.body[b].pred = PoseFilter::at_rest(t_s, priors_[b].T_w_b, priors_[b].cov,
                                           config_.max_angular_speed_radps, config_.max_speed_mps);
      body_T[b] = priors_[b].T_w_b;
      body_cov[b] = priors_[b].cov;
      body_src[b] = PredictionSource::kPrior;
    }
  }

  w.pred.assign(marks_.size(), {});
  w.pred_track.assign(marks_.size(), {});
  w.pred_body.assign(marks_.size(), {});
  w.lost.assign(bodies_.size(), false);
  const double gate3 = chi2_gate_[3];
  for (size_t m = 0; m < marks_.size(); ++m) {
    const MarkInfo& info = marks_[m];
    const MarkTrack& mt = mark_tracks_[m];
    const int last = mt.count - 1;
    const int b = info.body;
    // Candidates: the mark's own track and its body's pose. The one with the smaller
    // covariance wins: a fresh mark track beats a body extrapolation, but a mark that has been
    // hidden for a while (its track covariance grows with the gap) is predicted from its body,
    // so its gate does not swallow its neighbours' observations.
    Work::Pred& from_track = w.pred_track[m];
    Work::Pred& from_body = w.pred_body[m];
    if (mt.count > 0 && t_s - mt.t_s[last] <= config_.track_max_gap_s) {
      const double dt = t_s - mt.t_s[last];
      const double accel = 0.5 * config_.max_acceleration_mps2 * dt * dt;
      if (mt.count == 2 && mt.t_s[1] > mt.t_s[0]) {
        const double r = dt / (mt.t_s[1] - mt.t_s[0]);
        from_track.p = mt.p_w[1] + r * (mt.p_w[1] - mt.p_w[0]);
        from_track.cov = (1 + r) * (1 + r) * mt.cov_w[1] + r * r * mt.cov_w[0] +
                         (accel * accel + floor2) * Mat3::Identity();
      } else {
        const double v = config_.max_speed_mps * dt;
        from_track.p = mt.p_w[last];
        from_track.cov = mt.cov_w[last] + (v * v + accel * accel + floor2) * Mat3::Identity();
      }
      from_track.source = PredictionSource::kMarkTrack;
      from_track.valid = true;
    }
    if (body_src[b] != PredictionSource::kNone) {
      from_body.p = body_T[b] * info.p_body;
      from_body.cov = point_covariance(body_T[b], info.p_body, body_cov[b]) +
                      (info.survey_sigma_m * info.survey_sigma_m + floor2) * Mat3::Identity();
      from_body.source = body_src[b];
      from_body.valid = true;
      // A pose extrapolated over a long gap: once a mark's gate (chi-square(3)) reaches past
      // the body's smallest mark spacing in EVERY direction (smallest eigenvalue; a pose poorly
      // known about one axis only, e.g. a row's roll, still tells neighbours apart in the
      // images), it can only make its marks (and other bodies' marks) ambiguous. The body is
      // then lost: searched for instead (reacquisition.cpp). The smallest eigenvalue is at most
      // trace / 3, so it is computed only past that cheap bound (never on the tracking path).
      const double limit2 = min_mark_spacing_[b] * min_mark_spacing_[b];
      if (body_src[b] == PredictionSource::kBodyTrack &&
          gate3 * from_body.cov.trace() / 3 > limit2 &&
          gate3 * Eigen::SelfAdjointEigenSolver<Mat3>(from_body.cov, Eigen::EigenvaluesOnly)
                      .eigenvalues()[0] >
              limit2)
        w.lost[b] = true;
    }
  }
  for (size_t b = 0; b < bodies_.size(); ++b)
    if (w.lost[b]) {
      w.body[b].predicted = false;
      ++w.counts.lost_body;
    }
  for (size_t m = 0; m < marks_.size(); ++m) {
    const Work::Pred& from_track = w.pred_track[m];
    Work::Pred from_body = w.pred_body[m];
    if (w.lost[marks_[m].body]) from_body.valid = false;
    auto& pr = w.pred[m];
    if (from_track.valid && (!from_body.valid || from_track.cov.trace() <= from_body.cov.trace()))
      pr = from_track;
    else
      pr = from_body;
    if (pr.valid && pr.source == PredictionSource::kPrior) w.acquired = true;
  }
}

}  // namespace storetrack::match
