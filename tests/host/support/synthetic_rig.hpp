// Small analytic rig for host geometry tests that do not need the full simulator: four
// cameras on a pod looking down (world +z) at a volume around (0, 0, 2) m.
#pragma once

#include <random>

#include <Eigen/Geometry>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/geometry/transform.hpp"

namespace storetrack::test {

/// T_c_w of a camera at `centre_w` whose optical axis points at `target_w`.
inline geometry::Transform look_at(const geometry::Vec3& centre_w, const geometry::Vec3& target_w) {
  const geometry::Vec3 z = (target_w - centre_w).normalized();
  geometry::Vec3 x = geometry::Vec3::UnitX().cross(z);  // image x roughly along world -y...
  if (x.norm() < 1e-6) x = geometry::Vec3::UnitY().cross(z);
  x.normalize();
  const geometry::Vec3 y = z.cross(x);
  geometry::Mat3 R_w_c;
  R_w_c.col(0) = x;
  R_w_c.col(1) = y;
  R_w_c.col(2) = z;
  geometry::Transform T_w_c = geometry::Transform::Identity();
  T_w_c.linear() = R_w_c;
  T_w_c.translation() = centre_w;
  return T_w_c.inverse();
}

inline camera::Intrinsics test_intrinsics() {
  camera::Intrinsics in;
  in.fx = 1400;
  in.fy = 1401;
  in.cx = 955.0;
  in.cy = 515.0;
  in.dist = {-0.12, 0.05, 0.0004, -0.0003, 0.0, 0, 0, 0};
  return in;
}

/// Four cameras; covariances are realistic orders of magnitude (docs/uncertainty.md).
inline camera::RigCalibration synthetic_rig(int cameras = 4) {
  camera::RigCalibration rig;
  const geometry::Vec3 target(0, 0, 2.0);
  const geometry::Vec3 centres[4] = {
      {0.6, -0.4, 0}, {0.6, 0.4, 0}, {-0.6, -0.4, 0}, {-0.6, 0.4, 0}};
  for (int c = 0; c < cameras; ++c) {
    camera::CalibratedCamera cam;
    cam.camera_id = c;
    cam.unit_id = c / 2;
    cam.model = camera::CameraModel(test_intrinsics());
    cam.T_c_w = look_at(centres[c], target);
    camera::IntrinsicVector sd = camera::IntrinsicVector::Zero();
    sd << 0.5, 0.5, 0.3, 0.3, 0, 2e-4, 4e-4, 2e-5, 2e-5, 0, 0, 0, 0;
    cam.intrinsic_covariance = sd.cwiseAbs2().asDiagonal();
    cam.intrinsic_covariance(0, 1) = cam.intrinsic_covariance(1, 0) = 0.8 * 0.25;  // fx-fy
    geometry::Vec6 esd;
    esd << 5e-5, 5e-5, 5e-5, 1e-4, 1e-4, 1e-4;
    cam.extrinsic_covariance = esd.cwiseAbs2().asDiagonal();
    cam.exposure_offset_ns = 0;
    cam.exposure_offset_sigma_ns = 20000;  // 20 us
    rig.cameras.push_back(cam);
  }
  return rig;
}

}  // namespace storetrack::test
