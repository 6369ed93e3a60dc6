// FtiSample pose fields shared by ExposureProcessor (solved poses) and PoseTracker
// (extrapolated poses), so that both fill the sample the same way.
#pragma once

#include <array>

#include "storetrack/geometry/transform.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/pipeline/pose_output.hpp"
#include "storetrack/uncertainty/sources.hpp"

namespace storetrack::pipeline {

/// (x, y, z, yaw, pitch, roll) of T_p_s.
geometry::Vec6 xyz_ypr(const geometry::Transform& T);

/// Pose, standard uncertainties, correlations and budget (RSS over x, y, z per source; survey
/// reported with the extrinsics) of (x, y, z, yaw, pitch, roll) with covariance `cov`.
void write_pose_fields(const geometry::Vec6& xyz_ypr, const geometry::Mat6& cov,
                       const std::array<geometry::Mat6, uncertainty::kNumSources>& cov_by_source,
                       msg::FtiSample& s);

/// Pose, uncertainty, correlation and budget fields set to their invalid value (NaN).
void clear_pose_fields(msg::FtiSample& s);

}  // namespace storetrack::pipeline
