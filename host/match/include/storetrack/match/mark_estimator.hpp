// THE estimator of a mark's position (estimation/triangulate's Gauss-Newton on the raw-pixel
// reprojection error): how a view of the mark is put to it and how it is started. The matcher's
// estimate (MarkMatcher::triangulate) and the processor's Monte Carlo draws, which repeat that
// estimator on drawn pixels and calibration, both build their views and options here; the
// re-acquisition search builds its views here too.
#pragma once

#include "storetrack/camera/camera_model.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/triangulate/triangulate.hpp"

namespace storetrack::match {

/// `camera`'s view of a mark at raw pixel `pixel_px`, centroid standard uncertainty `sigma_px`,
/// weighted by `information_px` = (sigma_px^2 I + calibration pixel covariance at the mark)^-1
/// (uncertainty::view_information). A mark moving at `*velocity_w` (nullptr: no motion known)
/// was seen displaced by velocity * `time_offset_s`, the offset of this camera's exposure from
/// the reference time (plus, in a Monte Carlo draw, that offset's drawn error).
inline triangulate::Observation estimator_view(const camera::CalibratedCamera& camera,
                                               const geometry::Vec2& pixel_px, double sigma_px,
                                               const geometry::Mat2& information_px,
                                               const geometry::Vec3* velocity_w = nullptr,
                                               double time_offset_s = 0) {
  triangulate::Observation view;
  view.model = &camera.model;
  view.T_c_w = camera.T_c_w;
  view.pixel_px = pixel_px;
  view.sigma_px = sigma_px;
  view.information_px = information_px;
  if (velocity_w != nullptr) view.displacement_w = *velocity_w * time_offset_s;
  return view;
}

/// The estimator's options, started at `initial_p_w` (the mark's prediction; in a draw, the
/// nominal estimate). Gauss-Newton converges quadratically from inside the gate: after a step
/// shorter than 10 um the remaining error is of the order of its square over the depth
/// (~1e-10 m at 1 m), far below any mark's sigma (>= 50 um), so the estimate does not depend on
/// where it started; the last pass's Jacobians are 10 um from the solution (a relative change of
/// ~1e-5 in the covariance and gains).
inline triangulate::Options estimator_options(const geometry::Vec3& initial_p_w) {
  triangulate::Options options;
  options.initial_p_w = initial_p_w;
  options.step_tolerance_m = 1e-5;
  return options;
}

}  // namespace storetrack::match
