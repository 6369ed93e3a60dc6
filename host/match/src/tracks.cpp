// Track update after an exposure: the marks' last two positions and the bodies' pose filters
// (their motion states' filter part, BodyMotion).
#include "matcher_work.hpp"

namespace storetrack::match {

void MarkMatcher::update_tracks(const Work& w, double t_s) {
  for (size_t m = 0; m < marks_.size(); ++m) {
    if (!w.tri[m].valid) continue;
    MarkTrack& mt = mark_tracks_[m];
    if (mt.count > 0 && t_s - mt.t_s[mt.count - 1] > config_.track_max_gap_s) mt.count = 0;
    if (mt.count == 2) {
      mt.t_s[0] = mt.t_s[1];
      mt.p_w[0] = mt.p_w[1];
      mt.cov_w[0] = mt.cov_w[1];
      mt.count = 1;
    }
    mt.t_s[mt.count] = t_s;
    mt.p_w[mt.count] = w.tri[m].p;
    mt.cov_w[mt.count] = w.tri[m].cov;
    ++mt.count;
  }
  for (size_t b = 0; b < bodies_.size(); ++b) {
    PoseFilter& filter = motion_[b].filter;
    if (w.body[b].updated) {
      filter = w.body[b].post;
      filter.valid = true;
    } else if (w.fitted[b]) {
      // (Re-)acquired by a layout fit: a new filter with the fit's pose covariance, at rest with
      // the a-priori spread of the rates (MatcherConfig::max_speed_mps, max_angular_speed_radps).
      filter = PoseFilter::at_rest(t_s, w.T_w_b[b], w.cov_b[b], config_.max_angular_speed_radps,
                                   config_.max_speed_mps);
    }
  }
}

}  // namespace storetrack::match
