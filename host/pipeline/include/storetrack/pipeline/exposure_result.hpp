// What the host knows about one exposure after processing it: the triangulated marks, the
// body poses and the relative store pose with their uncertainty by source, the rigid-body
// checks and the FtiSample (host/pipeline ExposureProcessor writes it, docs/uncertainty.md).
#pragma once

#include <array>
#include <vector>

#include <Eigen/Core>

#include "storetrack/geometry/transform.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/pose/pose_result.hpp"
#include "storetrack/rigid/rigid_check.hpp"
#include "storetrack/time/time.hpp"
#include "storetrack/uncertainty/calibration_factors.hpp"
#include "storetrack/uncertainty/sources.hpp"

namespace storetrack::pipeline {

using pose::PoseResult;
using pose::zero_by_source;

/// A triangulated mark.
struct MarkResult {
  int id = -1;
  char body = '?';  ///< 'p' pylon, 's' store, '?' other
  geometry::Vec3 p_w = geometry::Vec3::Zero();
  geometry::Mat3 cov_w = geometry::Mat3::Zero();  ///< total 3x3 covariance [m^2]
  std::array<geometry::Mat3, uncertainty::kNumSources> cov_by_source =
      zero_by_source<geometry::Mat3>();                ///< survey: zero
  geometry::Vec3 velocity_w = geometry::Vec3::Zero();  ///< from tracking (zero if unknown)
  bool velocity_valid = false;
  /// p_w is corrected for the mark's motion between the cameras' exposures (velocity from the
  /// track's last two positions; at a track's second exposure the velocity states only the
  /// time-offset uncertainty).
  bool motion_corrected = false;
  bool excluded = false;  ///< removed by the rigid-body test
  struct ObservationResidual {
    int camera_id = -1;
    int mark_index = -1;                                  ///< index in that camera's marks
    geometry::Vec2 residual_px = geometry::Vec2::Zero();  ///< observed - reprojected
    double sigma_px = 0;
    /// The view's weight in the triangulation: (sigma^2 I + calibration pixel covariance)^-1.
    geometry::Mat2 information_px = geometry::Mat2::Identity();
  };
  std::vector<ObservationResidual> observations;
  double chi2 = 0;  ///< sum of residual^T information_px residual over observations
  /// Loadings on the common calibration factors (3 x factors().num_factors()).
  uncertainty::Loadings3 loadings;
};

struct ExposureResult {
  msg::FtiSample sample{};
  std::uint32_t trigger_seq = 0;
  time::TaiNs reference_mid_tai_ns = 0;
  int cameras_used = 0;
  std::vector<MarkResult> marks;
  rigid::RigidCheckResult pylon_check, store_check;
  PoseResult T_w_p, T_w_s, T_p_s;
  /// A body pose was fitted to marks seen by single cameras (resection; sample.status
  /// kSingleView): its uncertainty is larger along the cameras' lines of sight.
  bool single_view_pose = false;
  /// (x, y, z, yaw, pitch, roll) of T_p_s and its covariance (what the FtiSample carries).
  Eigen::Matrix<double, 6, 1> xyz_ypr = Eigen::Matrix<double, 6, 1>::Zero();
  geometry::Mat6 cov_xyz_ypr = geometry::Mat6::Zero();
  std::array<geometry::Mat6, uncertainty::kNumSources> cov_xyz_ypr_by_source =
      zero_by_source<geometry::Mat6>();

  /// Set by PoseTracker::update() when T_p_s could not be solved from this exposure and was
  /// predicted from the track instead (sample.status kValid | kExtrapolated). xyz_ypr,
  /// cov_xyz_ypr (including the process noise) and cov_xyz_ypr_by_source then describe the
  /// prediction; T_p_s stays invalid.
  bool extrapolated = false;
  geometry::Transform T_p_s_extrapolated = geometry::Transform::Identity();
  geometry::Mat6 cov_T_p_s_extrapolated = geometry::Mat6::Zero();  ///< left perturbation
  double extrapolation_horizon_s = 0;  ///< time since the last solved T_p_s

  const MarkResult* find_mark(int id) const;
};

}  // namespace storetrack::pipeline
