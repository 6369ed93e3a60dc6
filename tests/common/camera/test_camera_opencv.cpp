// Agreement of storetrack::camera with cv::projectPoints (OpenCV 4.6), the reference
// implementation of the parameter vector we claim compatibility with. Host-side test only.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "storetrack/camera/camera_model.hpp"

namespace storetrack::camera {
namespace {

using geometry::Vec3;

/// The model's pixels of `points_w` against OpenCV's `image` (each within 1e-9 px); the worst.
double expect_same_pixels(const CameraModel& cam, const geometry::Transform& T_c_w,
                          const std::vector<Vec3>& points_w, const std::vector<cv::Point2d>& image,
                          int trial) {
  double worst_px = 0;
  for (size_t i = 0; i < points_w.size(); ++i) {
    const auto px = cam.project_world(T_c_w, points_w[i]);
    EXPECT_TRUE(px) << "trial " << trial << " point " << i;
    if (!px) continue;
    const double err = std::hypot(px->x() - image[i].x, px->y() - image[i].y);
    worst_px = std::max(worst_px, err);
    EXPECT_LT(err, 1e-9) << "trial " << trial << " point " << i;
  }
  return worst_px;
}

TEST(CameraOpenCv, ProjectPointsAgreesTo1e9Px) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  double worst_px = 0;
  for (int trial = 0; trial < 200; ++trial) {
    Intrinsics in;
    in.fx = 1300 + 300 * u(rng);
    in.fy = in.fx * (1 + 0.01 * u(rng));
    in.cx = 959.5 + 30 * u(rng);
    in.cy = 511.5 + 30 * u(rng);
    in.skew = 0;  // cv::projectPoints ignores the skew entry of the camera matrix
    const bool rational = trial % 2 == 0;
    in.dist = {0.3 * u(rng), 0.1 * u(rng), 1e-3 * u(rng), 1e-3 * u(rng), 0.05 * u(rng), 0, 0, 0};
    if (rational)
      in.dist = {in.dist[0], in.dist[1],   in.dist[2],    in.dist[3],
                 in.dist[4], 0.1 * u(rng), 0.02 * u(rng), 0.005 * u(rng)};
    const CameraModel cam(in);
    const Vec3 rotvec(0.5 * u(rng), 0.5 * u(rng), 0.5 * u(rng));
    const Vec3 trans(u(rng), u(rng), 2 * u(rng));
    const geometry::Transform T_c_w = geometry::make_transform(rotvec, trans);

    std::vector<cv::Point3d> object;
    std::vector<geometry::Vec3> points_w;
    for (int i = 0; i < 50; ++i) {
      const double z = 2 + 18 * (u(rng) + 1) / 2;
      const Vec3 p_cam(0.6 * u(rng) * z, 0.35 * u(rng) * z, z);
      const Vec3 p_w = T_c_w.inverse() * p_cam;
      points_w.push_back(p_w);
      object.emplace_back(p_w.x(), p_w.y(), p_w.z());
    }
    const cv::Mat K = (cv::Mat_<double>(3, 3) << in.fx, 0, in.cx, 0, in.fy, in.cy, 0, 0, 1);
    const cv::Mat dist(1, rational ? 8 : 5, CV_64F, const_cast<double*>(in.dist.data()));
    const cv::Mat rvec = (cv::Mat_<double>(3, 1) << rotvec.x(), rotvec.y(), rotvec.z());
    const cv::Mat tvec = (cv::Mat_<double>(3, 1) << trans.x(), trans.y(), trans.z());
    std::vector<cv::Point2d> image;
    cv::projectPoints(object, rvec, tvec, K, dist, image);
    worst_px = std::max(worst_px, expect_same_pixels(cam, T_c_w, points_w, image, trial));
  }
  RecordProperty("worst_px", std::to_string(worst_px));
}

TEST(CameraOpenCv, FisheyeProjectPointsAgreesTo1e9Px) {
  // Kannala-Brandt against cv::fisheye::projectPoints (its skew is alpha = skew / fx), points
  // from the axis out to 89 degrees.
  std::mt19937_64 rng(12);
  std::uniform_real_distribution<double> u(-1, 1);
  double worst_px = 0;
  for (int trial = 0; trial < 100; ++trial) {
    Intrinsics in;
    in.lens_model = LensModel::kKannalaBrandt;
    in.fx = 330 + 60 * u(rng);
    in.fy = in.fx * (1 + 0.01 * u(rng));
    in.cx = 959.5 + 20 * u(rng);
    in.cy = 511.5 + 20 * u(rng);
    in.skew = u(rng);
    in.dist = {0.05 * u(rng), 0.02 * u(rng), 0.005 * u(rng), 0.001 * u(rng), 0, 0, 0, 0};
    const CameraModel cam(in);
    const Vec3 rotvec(0.5 * u(rng), 0.5 * u(rng), 0.5 * u(rng));
    const Vec3 trans(u(rng), u(rng), 2 * u(rng));
    const geometry::Transform T_c_w = geometry::make_transform(rotvec, trans);

    std::vector<cv::Point3d> object;
    std::vector<geometry::Vec3> points_w;
    for (int i = 0; i < 50; ++i) {
      const double theta = 89.0 * M_PI / 180 * (u(rng) + 1) / 2, phi = M_PI * u(rng);
      const Vec3 p_cam =
          (1 + 9 * (u(rng) + 1) / 2) *
          Vec3(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
      const Vec3 p_w = T_c_w.inverse() * p_cam;
      points_w.push_back(p_w);
      object.emplace_back(p_w.x(), p_w.y(), p_w.z());
    }
    const cv::Matx33d K(in.fx, 0, in.cx, 0, in.fy, in.cy, 0, 0, 1);
    const cv::Vec4d dist(in.dist[0], in.dist[1], in.dist[2], in.dist[3]);
    const cv::Vec3d rvec(rotvec.x(), rotvec.y(), rotvec.z());
    const cv::Vec3d tvec(trans.x(), trans.y(), trans.z());
    std::vector<cv::Point2d> image;
    cv::fisheye::projectPoints(object, image, rvec, tvec, K, dist, in.skew / in.fx);
    worst_px = std::max(worst_px, expect_same_pixels(cam, T_c_w, points_w, image, trial));
  }
  RecordProperty("worst_px", std::to_string(worst_px));
}

}  // namespace
}  // namespace storetrack::camera
