// A rig with its parameters moved by e in the calibration file's joint layout: per camera the
// packed intrinsics, then the left perturbation of T_c_w (camera::kJointBlockSize each). The
// tests draw a "true" rig from a stated one and its joint covariance with it, or the reverse.
#pragma once

#include <cstddef>

#include <Eigen/Core>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/geometry/transform.hpp"

namespace storetrack::test {

inline camera::RigCalibration perturbed_rig(const camera::RigCalibration& rig,
                                            const Eigen::VectorXd& e) {
  camera::RigCalibration out = rig;
  for (std::size_t c = 0; c < out.cameras.size(); ++c) {
    camera::CalibratedCamera& cam = out.cameras[c];
    const camera::Intrinsics in = cam.model.intrinsics();
    const auto base = static_cast<Eigen::Index>(camera::kJointBlockSize * c);
    const camera::IntrinsicVector v = camera::pack(in) + e.segment<camera::kNumIntrinsics>(base);
    cam.model = camera::CameraModel(camera::unpack(v, in.width, in.height, in.lens_model));
    cam.T_c_w = geometry::perturb_left(cam.T_c_w, e.segment<6>(base + camera::kNumIntrinsics));
  }
  return out;
}

}  // namespace storetrack::test
