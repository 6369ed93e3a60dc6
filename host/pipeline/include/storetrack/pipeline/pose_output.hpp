// The pose as the FtiSample reports it: (x, y, z, yaw, pitch, roll) of T_p_s, and its Jacobian,
// which maps a covariance or loadings of T_p_s's left perturbation onto those quantities (the
// processor's cov_xyz_ypr; storetrack-post's differences of a substituted input).
#pragma once

#include "storetrack/geometry/transform.hpp"

namespace storetrack::pipeline {

/// d(x, y, z, yaw, pitch, roll)/d(left perturbation of T_p_s).
geometry::Mat6 output_jacobian(const geometry::Transform& T_p_s);

}  // namespace storetrack::pipeline
