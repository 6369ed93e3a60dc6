// Predicted uncertainty of a triangulated point from a rig calibration and its (joint)
// covariance: the host's triangulation (estimation/triangulate) and its first-order propagation
// dp/dtheta = -K_i dpixel_i/dtheta (docs/uncertainty.md), shared by `register`, `compare` and
// `uncertainty-map` (docs/calibration.md).
#pragma once

#include <span>
#include <vector>

#include <Eigen/Core>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/triangulate/triangulate.hpp"

namespace storetrack::calib {

/// One camera's pixel of a point: `slot` = index in RigCalibration::cameras.
struct SlotPixel {
  int slot = 0;
  geometry::Vec2 pixel_px = geometry::Vec2::Zero();
};

/// d(p_w)/d(calibration parameters) of a triangulation (3 x kJointBlockSize * cameras, the
/// joint covariance's layout): -K_i [dpixel_i/d(intrinsics), dpixel_i/d(T_c_w perturbation)]
/// in observation i's camera block. `slots[i]` is observation i's camera slot.
Eigen::MatrixXd calibration_sensitivity(const triangulate::Result& tri, std::span<const int> slots,
                                        int num_cameras);

/// Pixels of a world point in every camera that images it (in front, inside the image:
/// -0.5 <= u < width - 0.5, the same for v).
std::vector<SlotPixel> visible_pixels(const camera::RigCalibration& rig, const geometry::Vec3& p_w);

struct PointUncertainty {
  geometry::Vec3 p_w = geometry::Vec3::Zero();
  geometry::Mat3 cov_centroid = geometry::Mat3::Zero();     ///< (J^T W J)^-1 [m^2]
  geometry::Mat3 cov_calibration = geometry::Mat3::Zero();  ///< G Sigma_theta G^T [m^2]
  Eigen::MatrixXd sensitivity;  ///< G = dp/dtheta (calibration_sensitivity)
  geometry::Mat3 covariance() const { return cov_centroid + cov_calibration; }
};

/// Triangulates `pixels` (>= 2 cameras) through `rig` with centroid sigma `sigma_px` and
/// propagates `calibration_covariance` (joint layout; rig.full_joint_covariance() for a file
/// without a joint covariance). False when the triangulation fails.
bool triangulate_with_uncertainty(const camera::RigCalibration& rig,
                                  const Eigen::MatrixXd& calibration_covariance,
                                  std::span<const SlotPixel> pixels, double sigma_px,
                                  PointUncertainty& out);

}  // namespace storetrack::calib
