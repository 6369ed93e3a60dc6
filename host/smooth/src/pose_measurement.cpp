#include <algorithm>

#include "storetrack/smooth/pose_smoother.hpp"

namespace storetrack::smooth {

PoseMeasurement measurement_from(const pipeline::ExposureResult& r) {
  constexpr auto kCentroid =
      static_cast<std::size_t>(uncertainty::index(uncertainty::Source::kCentroid));
  PoseMeasurement m;
  m.t_ns = r.reference_mid_tai_ns;
  // An extrapolated sample is the tracker's prediction, not a measurement.
  const pipeline::PoseResult& pose = r.T_p_s;
  m.solved = pose.valid && pose.loadings.cols() > 0;
  if (!m.solved) return m;
  m.T_p_s = pose.T;
  // Independent between exposures: the centroid noise. The time-offset source (kSync) is a
  // calibrated latency per camera plus a per-exposure jitter, stated as one factor per camera:
  // taken as shared, the conservative side for the smoothed pose (docs/post-processing.md).
  m.cov_noise = pose.cov_by_source[kCentroid];
  const Eigen::Index nz = pose.loadings.cols(), ns = pose.survey_loadings.cols();
  m.shared.resize(6, nz + ns);
  m.shared.leftCols(nz) = pose.loadings;
  if (ns > 0) m.shared.rightCols(ns) = pose.survey_loadings;
  // The pylon's: the same calibration factors; its survey columns are the pylon marks', the
  // first ones of T_p_s's survey columns.
  const pipeline::PoseResult& pylon = r.T_w_p;
  m.pylon_solved = pylon.valid && pylon.loadings.cols() == nz;
  if (!m.pylon_solved) return m;
  m.T_w_p = pylon.T;
  m.pylon_cov_noise = pylon.cov_by_source[kCentroid];
  m.pylon_shared = SharedLoadings6::Zero(6, nz + ns);
  m.pylon_shared.leftCols(nz) = pylon.loadings;
  const Eigen::Index np = std::min(ns, pylon.survey_loadings.cols());
  if (np > 0) m.pylon_shared.middleCols(nz, np) = pylon.survey_loadings.leftCols(np);
  return m;
}

}  // namespace storetrack::smooth
