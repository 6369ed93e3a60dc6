// Builds host inputs from the simulator's fast mode, with the simulator's truth ids, and the
// truth the host's estimates must be compared with.
#pragma once

#include <string>

#include "storetrack/pipeline/aligned_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/sim/simulator.hpp"

namespace storetrack::test {

inline std::string scenario_path(const std::string& name) {
  // Appended in place: GCC 12 -O3 reports a false -Warray-bounds on the chained operator+.
  std::string path = STORETRACK_SCENARIO_DIR;
  path.append("/").append(name).append(".json");
  return path;
}

struct SimExposure {
  pipeline::AlignedExposure exposure;
  pipeline::MarkIds ids;
};

/// The true rig with its calibration stated perfect (zero covariances, no joint covariance,
/// zero sync sigma): the host's stated u is then its centroid part alone.
inline camera::RigCalibration perfect_rig(const sim::Simulator& sim) {
  camera::RigCalibration rig = sim.true_rig();
  for (camera::CalibratedCamera& c : rig.cameras) {
    c.intrinsic_covariance.setZero();
    c.extrinsic_covariance.setZero();
    c.exposure_offset_sigma_ns = 0;
  }
  rig.joint_covariance.resize(0, 0);  // the registration's cross terms: perfect too
  return rig;
}

inline SimExposure make_exposure(const sim::Simulator& sim, int k) {
  SimExposure out;
  out.exposure.cameras.resize(static_cast<size_t>(sim.num_cameras()));
  out.ids.resize(out.exposure.cameras.size());
  for (int c = 0; c < sim.num_cameras(); ++c) {
    std::vector<int> ids;
    sim.observe(k, c, out.exposure.cameras[static_cast<size_t>(c)], &ids);
    out.ids[static_cast<size_t>(c)] = ids;
  }
  out.exposure.trigger_seq = out.exposure.cameras[0].trigger_seq;
  out.exposure.exposure_mid_tai_ns = pipeline::exposure_mid_tai_ns(out.exposure.cameras[0]);
  return out;
}

/// The cameras ride on the pylon pod, so the host's world frame is the NOMINAL one: the truth
/// position p_w(t) seen through static extrinsics is T_w_p0 T_w_p(t)^-1 p_w(t).
inline geometry::Transform host_world_from_true_world(const sim::Simulator& sim, time::TaiNs t) {
  return sim.T_w0_w_at(t);
}

inline geometry::Vec3 true_mark_in_host_world(const sim::Simulator& sim, int id, time::TaiNs t) {
  return host_world_from_true_world(sim, t) * sim.mark_position_w(id, t);
}

}  // namespace storetrack::test
