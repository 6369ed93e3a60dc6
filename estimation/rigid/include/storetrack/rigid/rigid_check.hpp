// Rigid-body distance checks (IPEV SisTrO: every reference-mark pair of a rigid body keeps its
// surveyed distance). Each pair's distance error is tested against its PREDICTED standard
// uncertainty, not a fixed gate: z^2 = (d - d_survey)^2 / u^2(d - d_survey) ~ chi-square(1),
// where u^2 carries both marks' triangulation covariances, their cross-covariance through the
// shared calibration errors, and both survey sigmas (GUM JCGM 100:2008, 5.2). The per-pair
// threshold is Bonferroni-corrected so that an intact body fails with probability <= alpha.
// Failing bodies lose their worst mark (largest mean z^2 over its pairs), then are re-tested.
#pragma once

#include <span>
#include <vector>

#include <Eigen/Core>

#include "storetrack/geometry/transform.hpp"

namespace storetrack::rigid {

/// One triangulated mark of the body. Its error model: e = n + L z with n ~ N(0, cov_independent)
/// private to the mark and z ~ N(0, I) the calibration factors shared by all marks.
struct MarkEstimate {
  int id = -1;
  geometry::Vec3 p_body = geometry::Vec3::Zero();  ///< surveyed position
  double survey_sigma_m = 0;                       ///< per axis
  geometry::Vec3 p_w = geometry::Vec3::Zero();     ///< triangulated position
  geometry::Mat3 cov_independent = geometry::Mat3::Zero();
  /// Loadings on the common factors (uncertainty::Loadings3); may be null: no common part.
  const Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor>* loadings = nullptr;
};

struct RigidCheckConfig {
  double false_alarm_probability = 1e-3;  ///< per body and exposure, for an intact body
  int min_marks = 3;                      ///< never exclude below this many marks
  /// Every pair's sigma and z2 in the result (the host's rigid-body CSV). Off, only the decision
  /// is made in full: the pairs are first tested without their shared calibration variance,
  /// which can only raise z2, and when none exceeds the threshold the body passes, exactly as
  /// the full test would, and `pairs` stays empty; otherwise the full test runs.
  bool pair_statistics = true;
};

struct PairTest {
  int id_a = -1, id_b = -1;
  double distance_m = 0, surveyed_m = 0;
  double sigma_m = 0;  ///< predicted standard uncertainty of distance_m - surveyed_m
  double z2 = 0;       ///< ((distance - surveyed) / sigma)^2
};

struct RigidCheckResult {
  /// All pairs of the marks given (before exclusion); empty when a body passed without them
  /// (RigidCheckConfig::pair_statistics off).
  std::vector<PairTest> pairs;
  std::vector<int> excluded_ids;  ///< in exclusion order
  std::vector<size_t> excluded;   ///< the same marks' positions in the span checked
  /// Per mark of the span: its mean z2 over its pairs in the last test (0 once excluded, all 0
  /// when `pairs` is empty); the worst is excluded next.
  std::vector<double> mean_z2;
  bool failed = false;           ///< at least one pair inconsistent in the first test
  bool consistent_after = true;  ///< remaining marks pass (false: stopped at min_marks)
  double pair_threshold_z2 = 0;  ///< threshold of the first test
};

/// Predicted standard uncertainty of |p_a - p_b| - |q_a - q_b|.
PairTest test_pair(const MarkEstimate& a, const MarkEstimate& b);

/// All pairs' tests, then the marks excluded one at a time (the worst mean z2) until the rest
/// pass. Writes every field of `result`, reusing its lists' storage (the per-exposure path).
void check_rigid_body(std::span<const MarkEstimate> marks, const RigidCheckConfig& config,
                      RigidCheckResult& result);

inline RigidCheckResult check_rigid_body(std::span<const MarkEstimate> marks,
                                         const RigidCheckConfig& config) {
  RigidCheckResult result;
  check_rigid_body(marks, config, result);
  return result;
}

}  // namespace storetrack::rigid
