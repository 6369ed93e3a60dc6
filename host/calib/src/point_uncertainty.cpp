#include "storetrack/calib/point_uncertainty.hpp"

#include "storetrack/uncertainty/calibration_factors.hpp"

namespace storetrack::calib {

Eigen::MatrixXd calibration_sensitivity(const triangulate::Result& tri, std::span<const int> slots,
                                        int num_cameras) {
  constexpr int kBlock = camera::kJointBlockSize;
  Eigen::MatrixXd G = Eigen::MatrixXd::Zero(3, kBlock * num_cameras);
  for (size_t i = 0; i < slots.size(); ++i)
    G.middleCols<kBlock>(kBlock * slots[i]) +=
        uncertainty::point_sensitivity(tri.gain[i], tri.jacobians[i]);
  return G;
}

std::vector<SlotPixel> visible_pixels(const camera::RigCalibration& rig,
                                      const geometry::Vec3& p_w) {
  std::vector<SlotPixel> out;
  for (size_t s = 0; s < rig.cameras.size(); ++s) {
    const camera::CalibratedCamera& cam = rig.cameras[s];
    const auto pixel = cam.model.project_world(cam.T_c_w, p_w);
    if (!pixel) continue;
    const auto& in = cam.model.intrinsics();
    if (pixel->x() < -0.5 || pixel->y() < -0.5 || pixel->x() >= in.width - 0.5 ||
        pixel->y() >= in.height - 0.5)
      continue;
    out.push_back({static_cast<int>(s), *pixel});
  }
  return out;
}

bool triangulate_with_uncertainty(const camera::RigCalibration& rig,
                                  const Eigen::MatrixXd& calibration_covariance,
                                  std::span<const SlotPixel> pixels, double sigma_px,
                                  PointUncertainty& out) {
  if (pixels.size() < 2) return false;
  std::vector<triangulate::Observation> obs(pixels.size());
  std::vector<int> slots(pixels.size());
  for (size_t i = 0; i < pixels.size(); ++i) {
    const camera::CalibratedCamera& cam = rig.cameras[static_cast<size_t>(pixels[i].slot)];
    obs[i].model = &cam.model;
    obs[i].T_c_w = cam.T_c_w;
    obs[i].pixel_px = pixels[i].pixel_px;
    obs[i].sigma_px = sigma_px;
    slots[i] = pixels[i].slot;
  }
  triangulate::Result tri;
  if (!triangulate::triangulate(obs, triangulate::Options{}, tri)) return false;
  out.p_w = tri.p_w;
  out.cov_centroid = tri.cov_centroid;
  out.sensitivity = calibration_sensitivity(tri, slots, static_cast<int>(rig.cameras.size()));
  out.cov_calibration = out.sensitivity * calibration_covariance * out.sensitivity.transpose();
  return true;
}

}  // namespace storetrack::calib
