// A solved pose with its uncertainty by source and its loadings on the shared errors: what the
// processor states for a body (host/pipeline ExposureResult) and what a body's motion state
// keeps of its last solutions (host/match BodyMotion), docs/uncertainty.md.
#pragma once

#include <array>

#include "storetrack/geometry/transform.hpp"
#include "storetrack/uncertainty/calibration_factors.hpp"
#include "storetrack/uncertainty/sources.hpp"

namespace storetrack::pose {

/// One zero matrix per uncertainty source (value-initialising an Eigen matrix leaves it unset).
template <class Matrix>
std::array<Matrix, uncertainty::kNumSources> zero_by_source() {
  std::array<Matrix, uncertainty::kNumSources> by_source;
  for (Matrix& m : by_source)
    m.setZero();
  return by_source;
}

/// A pose with its 6x6 covariance over the left perturbation (rx, ry, rz, tx, ty, tz).
struct PoseResult {
  bool valid = false;
  geometry::Transform T = geometry::Transform::Identity();
  geometry::Mat6 cov = geometry::Mat6::Zero();
  std::array<geometry::Mat6, uncertainty::kNumSources> cov_by_source =
      zero_by_source<geometry::Mat6>();
  int marks_used = 0;
  double chi2 = 0;  ///< fit chi-square (block-diagonal weights)
  /// Loadings of the pose perturbation on the common calibration factors (6 x
  /// factors().num_factors(); empty in Monte Carlo draws): cov_by_source of intrinsic,
  /// extrinsic and sync are their column blocks' L L^T. Lets consumers combine poses of
  /// different exposures with their shared calibration errors (PoseTracker).
  uncertainty::Loadings6 loadings;
  /// Loadings of the pose perturbation on the survey errors of the marks, whitened (column
  /// 3 i + a: axis a of the i-th mark of the pylon survey, then the store survey's after the
  /// pylon's 3 n_p columns; coefficient d(pose)/d(q) sigma_q). cov_by_source[survey] is their
  /// L L^T. Empty in Monte Carlo draws. The survey is one draw for the whole recording: lets
  /// consumers combine poses of different exposures with their shared survey errors
  /// (host/smooth).
  uncertainty::Loadings6 survey_loadings;
};

}  // namespace storetrack::pose
