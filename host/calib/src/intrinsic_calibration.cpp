// calibrate_intrinsics: gather one camera's views, Zhang start, LM, outlier rejection (repeat
// until the rejected set is stable), residuals and covariance (docs/calibration.md, "Method").
#include "storetrack/calib/intrinsic_calibration.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include "board_warp.hpp"
#include "intrinsic_covariance.hpp"
#include "intrinsic_refinement.hpp"
#include "outlier_gate.hpp"
#include "view_screening.hpp"
#include "zhang_initialisation.hpp"

namespace storetrack::calib {
namespace {

constexpr int kMaxRejectionRounds = 10;
// Floor on the largest angle between two board planes. Zhang (2000, sec. 5.1, "performance
// w.r.t. the orientation of the model plane") finds the calibration degrading fast as the planes
// approach parallel and best near 45 degrees; below 5 degrees it is not worth attempting.
constexpr double kMinBoardAngleDeg = 5.0;

std::vector<BoardView> camera_views(const ObservationSet& set, int camera,
                                    std::vector<SkippedView>& skipped) {
  std::map<int, BoardView> by_frame;
  for (const Observation& o : set.observations) {
    if (o.camera != camera) continue;
    BoardView& v = by_frame[o.frame];
    v.frame = o.frame;
    v.points.push_back(&o);
  }
  std::vector<BoardView> views;
  for (auto& [frame, view] : by_frame) {
    Eigen::Matrix3d homography;
    if (std::string why = degenerate_view_reason(view, &homography); why.empty()) {
      view.homography = homography;
      views.push_back(view);
    } else {
      skipped.push_back({frame, std::move(why)});
    }
  }
  return views;
}

/// Refuses a board whose points leave the plane z = 0 by more than kMaxBoardRelief of its larger
/// side, naming the first such point: the start uses (x, y) only.
void check_board_relief(const std::vector<BoardView>& views, const std::string& who) {
  const BoardWarp extent = BoardWarp::over(views);
  const double side = 2 * std::max(extent.x_half, extent.y_half);
  for (const BoardView& v : views)
    for (const Observation* o : v.points)
      if (std::abs(o->p_board.z()) > kMaxBoardRelief * side) {
        char text[256];
        std::snprintf(text, sizeof text,
                      "frame %d point %d: board z = %.4g m, more than %.0f %% of the board's "
                      "larger side (%.4g m); the start (a homography of the board's x, y) needs "
                      "a nearly planar board, with z measured from its plane",
                      v.frame, o->point_id, o->p_board.z(), 100 * kMaxBoardRelief, side);
        throw CalibrationError(who + text);
      }
}

/// Refuses too few usable views, naming the skipped ones (they are the usual cause).
void check_view_count(const std::vector<BoardView>& views, const std::vector<SkippedView>& skipped,
                      int min_views, const std::string& who) {
  if (static_cast<int>(views.size()) >= min_views) return;
  std::string named;
  for (const SkippedView& s : skipped)
    named += "; frame " + std::to_string(s.frame) + ": " + s.reason;
  throw CalibrationError(
      who + "too few usable views: " + std::to_string(views.size()) +
      " board poses, need at least " + std::to_string(min_views) +
      (skipped.empty() ? "" : " (" + std::to_string(skipped.size()) + " skipped" + named + ")"));
}

/// Zhang's start; a view whose start pose is not finite or puts the board behind the camera is
/// skipped (named) and the start recomputed without it.
ZhangStart usable_start(std::vector<BoardView>& views, std::vector<SkippedView>& skipped,
                        const ImageSize& size, const IntrinsicOptions& options, int min_views,
                        const std::string& who) {
  static const std::string no_pose =
      "no board pose from its homography (not finite, or the board behind the camera)";
  ZhangStart start = zhang_initialisation(views, size, options);
  std::vector<BoardView> kept;
  for (size_t i = 0; i < views.size(); ++i) {
    const geometry::Transform& T = start.T_c_b[i];
    if (T.matrix().allFinite() && T.translation().z() > 0)
      kept.push_back(views[i]);
    else
      skipped.push_back({views[i].frame, no_pose});
  }
  if (kept.size() == views.size()) return start;
  views = std::move(kept);
  check_view_count(views, skipped, min_views, who);
  start = zhang_initialisation(views, size, options);
  for (const geometry::Transform& T : start.T_c_b)
    if (!T.matrix().allFinite())
      throw CalibrationError(who + "no finite start from the remaining views");
  if (!std::isfinite(start.intrinsics.fx) || !std::isfinite(start.intrinsics.fy))
    throw CalibrationError(who + "no finite start from the remaining views");
  return start;
}

/// Weighted residuals (projected - observed) / sigma of every point, current parameters.
std::vector<std::vector<Eigen::Vector2d>> weighted_residuals(const std::vector<BoardView>& views,
                                                             const IntrinsicParameterMap& map,
                                                             const RefinementState& state) {
  const camera::CameraModel model(map.intrinsics(state.z.data()));
  std::vector<std::vector<Eigen::Vector2d>> out(views.size());
  for (size_t i = 0; i < views.size(); ++i) {
    const auto T = pose_transform(state.poses[i]);
    for (const Observation* o : views[i].points) {
      const auto pixel = model.project_world(T, state.warp.apply(o->p_board));
      const double w = 1.0 / o->weighting_sigma_px();
      out[i].push_back(pixel ? Eigen::Vector2d(w * (*pixel - o->pixel))
                             : Eigen::Vector2d::Constant(INFINITY));
    }
  }
  return out;
}

/// Refuses views whose boards are all (nearly) parallel. Then every view gives the same two
/// constraints on K (parallel planes share their circular points, imaged by h1 +- i h2 ~
/// K (r1 +- i r2)), so a 2-parameter family of cameras fits equally well, and in every member
/// of the family the boards are parallel: the test on the fitted poses holds whichever member
/// the solver found.
void check_board_orientations(const std::vector<BoardView>& views, const RefinementState& state,
                              const std::string& who) {
  std::vector<geometry::Vec3> normals;
  for (const PoseVector& pose : state.poses)
    normals.push_back(geometry::rotation_from_rotvec(pose.head<3>()).col(2));
  double widest_deg = 0;
  for (size_t a = 0; a < normals.size(); ++a)
    for (size_t c = a + 1; c < normals.size(); ++c)
      widest_deg = std::max(widest_deg,
                            std::acos(std::clamp(std::abs(normals[a].dot(normals[c])), 0.0, 1.0)));
  widest_deg *= 180 / M_PI;
  if (widest_deg >= kMinBoardAngleDeg) return;
  char angle[32];
  std::snprintf(angle, sizeof angle, "%.1f", widest_deg);
  throw CalibrationError(who + "degenerate views: the " + std::to_string(views.size()) +
                         " boards are (nearly) parallel to each other (largest angle between two "
                         "board planes " +
                         angle +
                         " deg, need >= 5), so the focal length and principal point "
                         "are not determined: tilt the board by 20-45 degrees about different "
                         "axes between views");
}

IntrinsicResult summarise(const std::vector<BoardView>& views,
                          const std::vector<std::vector<char>>& used,
                          const IntrinsicParameterMap& map, const RefinementState& state) {
  IntrinsicResult out;
  out.intrinsics = map.intrinsics(state.z.data());
  const auto weighted = weighted_residuals(views, map, state);
  double chi2 = 0, ssr_px = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    ViewResult v;
    v.frame = views[i].frame;
    v.T_c_b = pose_transform(state.poses[i]);
    double view_ssr = 0;
    for (size_t k = 0; k < views[i].points.size(); ++k) {
      const Observation& o = *views[i].points[k];
      const Eigen::Vector2d r_px = -weighted[i][k] * o.weighting_sigma_px();
      out.residuals.push_back({v.frame, o.point_id, r_px, !used[i][k]});
      if (!used[i][k]) {
        ++v.points_rejected;
        continue;
      }
      ++v.points_used;
      view_ssr += r_px.squaredNorm();
      chi2 += weighted[i][k].squaredNorm();
    }
    v.rms_px = v.points_used ? std::sqrt(view_ssr / v.points_used) : 0;
    ssr_px += view_ssr;
    out.points_used += v.points_used;
    out.points_rejected += v.points_rejected;
    out.views.push_back(v);
  }
  out.free_parameters =
      map.size() + 6 * static_cast<int>(views.size()) + (state.warp.fitted ? 2 : 0);
  const int dof = 2 * out.points_used - out.free_parameters;
  if (dof <= 0)
    throw CalibrationError(std::to_string(out.points_used) + " points give " +
                           std::to_string(2 * out.points_used) + " residuals for " +
                           std::to_string(out.free_parameters) +
                           " parameters: add views or points");
  out.rms_px = std::sqrt(ssr_px / out.points_used);
  const double variance = chi2 / dof;
  out.residual_sigma_px = std::sqrt(variance);
  const FitCovariance cov = fit_covariance(views, used, map, state, variance);
  out.covariance = cov.intrinsics;
  for (size_t i = 0; i < out.views.size(); ++i)
    out.views[i].pose_covariance = cov.poses[i];
  out.board_deflection = deflection_result(state.warp, cov.warp, "");
  return out;
}

}  // namespace

namespace {

/// Counts the distinct values (to 1 um) of one board coordinate.
int distinct_board_values(const std::vector<BoardView>& views, int axis) {
  std::vector<double> values;
  for (const BoardView& v : views)
    for (const Observation* o : v.points)
      values.push_back(o->p_board[axis]);
  std::sort(values.begin(), values.end());
  int distinct = values.empty() ? 0 : 1;
  for (size_t i = 1; i < values.size(); ++i)
    if (values[i] - values[i - 1] > 1e-6) ++distinct;
  return distinct;
}

/// The identifiability rule of the board deflection: a parabola along each board axis needs
/// points at >= 3 distinct x and >= 3 distinct y, and the bowl is told apart from the
/// distortion and the poses by its shape being shared across >= kMinDeflectionViews views.
/// "" when the rule holds, else why not.
constexpr int kMinDeflectionViews = 3;
std::string deflection_not_identifiable(const std::vector<BoardView>& views) {
  const int nx = distinct_board_values(views, 0), ny = distinct_board_values(views, 1);
  if (nx < 3 || ny < 3)
    return "the board has " + std::to_string(nx) + " distinct x and " + std::to_string(ny) +
           " distinct y coordinates (a bowl needs >= 3 of each)";
  if (static_cast<int>(views.size()) < kMinDeflectionViews)
    return std::to_string(views.size()) +
           " usable views (the deflection needs >= " + std::to_string(kMinDeflectionViews) + ")";
  return "";
}

}  // namespace

std::string decide_deflection(const std::vector<BoardView>& views, const IntrinsicOptions& options,
                              BoardWarp& warp, const std::string& who) {
  warp = BoardWarp::over(views);
  if (options.board_deflection == BoardDeflection::off) return "off (--board-deflection off)";
  const std::string why_not = deflection_not_identifiable(views);
  if (options.board_deflection == BoardDeflection::on && !why_not.empty())
    throw CalibrationError(who + "the board deflection cannot be fitted: " + why_not +
                           "; use --board-deflection off or auto");
  warp.fitted = why_not.empty();
  if (!warp.fitted) return "not fitted (auto): " + why_not;
  return options.board_deflection == BoardDeflection::on
             ? "fitted (--board-deflection on)"
             : "fitted (auto: >= 3 distinct board x and y, >= 3 views)";
}

IntrinsicResult calibrate_intrinsics(const ObservationSet& set, int camera,
                                     const IntrinsicOptions& options) {
  const std::string who = "camera " + std::to_string(camera) + ": ";
  if (std::none_of(set.observations.begin(), set.observations.end(),
                   [camera](const Observation& o) { return o.camera == camera; }))
    throw CalibrationError(who + "no observations of this camera");
  const auto size = set.image_sizes.find(camera);
  if (size == set.image_sizes.end())
    throw CalibrationError(who + "image size unknown (the CSV needs a '# image_size," +
                           std::to_string(camera) + ",W,H' line, or give --image-size)");
  std::vector<SkippedView> skipped;
  std::vector<BoardView> views = camera_views(set, camera, skipped);
  const int min_views = std::max(options.min_views, 2);
  check_view_count(views, skipped, min_views, who);
  check_board_relief(views, who);

  ZhangStart start = usable_start(views, skipped, size->second, options, min_views, who);
  // Zhang's pinhole focal length and principal point are the fisheye's start too (k = 0: the
  // equidistant lens, which agrees with the pinhole to O(theta^3) near the axis).
  start.intrinsics.lens_model = options.lens_model;
  const IntrinsicParameterMap map(options, start.intrinsics);
  RefinementState state{map.free_values(start.intrinsics), {}, {}};
  for (const auto& T : start.T_c_b) {
    PoseVector pose;
    pose << geometry::rotvec_from_rotation(T.linear()), T.translation();
    state.poses.push_back(pose);
  }
  const std::string deflection_reason = decide_deflection(views, options, state.warp, who);
  std::vector<std::vector<char>> used;  // every point to start
  for (const BoardView& v : views)
    used.emplace_back(v.points.size(), 1);
  int iterations = 0;
  for (int round = 0; round < kMaxRejectionRounds; ++round) {
    try {
      iterations += refine_intrinsics(views, used, map, state);
    } catch (const CalibrationError& e) {
      check_board_orientations(views, state, who);
      throw CalibrationError(who + e.what());
    }
    check_board_orientations(views, state, who);
    // Without a false alarm the gate keeps every point: no residual pass (a few % of a fit).
    if (!(options.outlier_false_alarm > 0)) break;
    auto next = outlier_gate(weighted_residuals(views, map, state), options.outlier_false_alarm);
    if (next == used) break;
    used = std::move(next);
  }
  IntrinsicResult out = summarise(views, used, map, state);
  out.board_deflection.reason = deflection_reason;
  out.iterations = iterations;
  std::sort(skipped.begin(), skipped.end(),
            [](const SkippedView& a, const SkippedView& b) { return a.frame < b.frame; });
  out.views_skipped = std::move(skipped);
  return out;
}

}  // namespace storetrack::calib
