// The live page's coverage overlay (docs/live-view.md): where the store's marks will fall in
// each camera's image along its expected trajectory, so an installer sees whether the store
// leaves a camera's view before the aircraft flies. The trajectory is an envelope of store
// poses relative to the pylon (host.json "live": {"store_envelope": [...]}, e.g. sampled from
// the scenario by tools/sim_setup.py); the pylon's pose is the last one the host solved, so the
// overlay follows the installed pylon rather than a drawing of it. Computed on the live
// server's thread, never on the real-time one.
#pragma once

#include <vector>

#include "storetrack/camera/camera_model.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/survey/survey.hpp"

namespace storetrack::live {

/// The store's marks in one camera's image at one pose of the envelope.
struct CoverageOutline {
  std::vector<geometry::Vec2> points;  ///< the marks in front of the camera [px], survey order
  std::vector<geometry::Vec2> hull;    ///< their convex hull, counter-clockwise (image axes)
  /// A mark outside the image (beyond its edge at -0.5 / size - 0.5) or behind the camera.
  bool leaves_image = false;
};

/// The store survey's marks through T_w_p * T_p_s into `camera`, one outline per envelope pose
/// T_p_s, in the envelope's order.
std::vector<CoverageOutline> coverage_outlines(const camera::CalibratedCamera& camera,
                                               const geometry::Transform& T_w_p,
                                               const std::vector<geometry::Transform>& envelope_p,
                                               const survey::RigidBodySurvey& store);

/// Convex hull (Andrew's monotone chain), counter-clockwise in a right-handed x-y frame,
/// without collinear points; fewer than 3 distinct points are returned as they are (distinct).
std::vector<geometry::Vec2> convex_hull(std::vector<geometry::Vec2> points);

}  // namespace storetrack::live
