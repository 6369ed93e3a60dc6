#include "sample_fields.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "storetrack/pose/body_pose.hpp"

namespace storetrack::pipeline {

using geometry::Mat3;
using geometry::Mat6;
using uncertainty::Source;

Mat6 output_jacobian(const geometry::Transform& T_p_s) {
  Mat6 J = Mat6::Zero();
  J.topRightCorner<3, 3>() = Mat3::Identity();
  J.bottomLeftCorner<3, 3>() = pose::ypr_jacobian(T_p_s.linear());
  return J;
}

geometry::Vec6 xyz_ypr(const geometry::Transform& T) {
  geometry::Vec6 v;
  v.head<3>() = T.translation();
  v.tail<3>() = geometry::ypr_from_rotation(T.linear());
  return v;
}

void write_pose_fields(const geometry::Vec6& v, const Mat6& cov,
                       const std::array<Mat6, uncertainty::kNumSources>& cov_by_source,
                       msg::FtiSample& s) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  s.x_m = static_cast<float>(v(0));
  s.y_m = static_cast<float>(v(1));
  s.z_m = static_cast<float>(v(2));
  s.yaw_rad = static_cast<float>(v(3));
  s.pitch_rad = static_cast<float>(v(4));
  s.roll_rad = static_cast<float>(v(5));
  const geometry::Vec6 u = cov.diagonal().cwiseMax(0.0).cwiseSqrt();
  s.u_x_m = static_cast<float>(u(0));
  s.u_y_m = static_cast<float>(u(1));
  s.u_z_m = static_cast<float>(u(2));
  s.u_yaw_rad = static_cast<float>(u(3));
  s.u_pitch_rad = static_cast<float>(u(4));
  s.u_roll_rad = static_cast<float>(u(5));
  size_t k = 0;
  for (int i = 0; i < 6; ++i)
    for (int j = i + 1; j < 6; ++j)
      s.correlation[k++] =
          (u(i) > 0 && u(j) > 0) ? static_cast<float>(cov(i, j) / (u(i) * u(j))) : nan;
  auto rss = [&](Source src) {
    return static_cast<float>(
        std::sqrt(std::max(0.0, cov_by_source[static_cast<size_t>(uncertainty::index(src))]
                                    .topLeftCorner<3, 3>()
                                    .trace())));
  };
  s.u_budget_centroid_m = rss(Source::kCentroid);
  s.u_budget_intrinsic_m = rss(Source::kIntrinsic);
  // The body-mark survey registers the pylon/store frames: reported with the extrinsics.
  s.u_budget_extrinsic_m = std::hypot(rss(Source::kExtrinsic), rss(Source::kSurvey));
  s.u_budget_sync_m = rss(Source::kSync);
  s.u_budget_process_m = rss(Source::kProcess);  // 0 unless extrapolated (PoseTracker)
}

void clear_pose_fields(msg::FtiSample& s) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  s.x_m = s.y_m = s.z_m = s.yaw_rad = s.pitch_rad = s.roll_rad = nan;
  s.u_x_m = s.u_y_m = s.u_z_m = s.u_yaw_rad = s.u_pitch_rad = s.u_roll_rad = nan;
  s.correlation.fill(nan);
  s.u_budget_centroid_m = s.u_budget_intrinsic_m = s.u_budget_extrinsic_m = s.u_budget_sync_m =
      s.u_budget_process_m = nan;
}

}  // namespace storetrack::pipeline
