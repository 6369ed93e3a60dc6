// calibrate_rig: each camera's intrinsic calibration (the start), extrinsics T_c_r along a chain
// of cameras that share views with the reference, board poses T_r_b, then one joint LM with the
// outlier gate (per camera, until the rejected set is stable), residuals and the joint
// covariance (docs/calibration.md, "Rig").
#include "storetrack/calib/rig_calibration.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <queue>
#include <set>
#include <string>

#include "outlier_gate.hpp"
#include "rig_refinement.hpp"
#include "storetrack/pose/body_pose.hpp"
#include "view_screening.hpp"

namespace storetrack::calib {
namespace {

constexpr int kMaxRejectionRounds = 10;

/// One camera's usable views (view_screening.hpp) by frame, and its intrinsic calibration.
struct CameraStart {
  int id = 0;
  std::map<int, BoardView> views;
  std::map<int, geometry::Transform> T_c_b;  ///< from the intrinsic calibration
  IntrinsicResult intrinsic;
};

std::vector<CameraStart> group_by_camera(const ObservationSet& set) {
  std::map<int, CameraStart> by_id;
  for (const Observation& o : set.observations) {
    CameraStart& c = by_id[o.camera];
    c.id = o.camera;
    BoardView& v = c.views[o.frame];
    v.frame = o.frame;
    v.points.push_back(&o);
  }
  std::vector<CameraStart> out;
  for (auto& [id, c] : by_id) {
    std::string reasons;
    std::erase_if(c.views, [&reasons](const auto& fv) {
      const std::string why = degenerate_view_reason(fv.second);
      if (!why.empty()) reasons += "; frame " + std::to_string(fv.first) + ": " + why;
      return !why.empty();
    });
    // Refused here, before the links are sought: "never seen with the reference" would hide why.
    if (c.views.empty())
      throw CalibrationError("camera " + std::to_string(id) + ": no usable view (all skipped" +
                             reasons + ")");
    out.push_back(std::move(c));
  }
  return out;
}

int common_views(const CameraStart& a, const CameraStart& b) {
  int n = 0;
  for (const auto& [frame, view] : a.views)
    n += b.views.count(frame) ? 1 : 0;
  return n;
}

/// T_b_a from the board points of every frame both saw, each in both camera frames through the
/// cameras' own board poses (weighted absolute orientation, equal weights).
geometry::Transform relative_pose(const CameraStart& a, const CameraStart& b) {
  std::vector<geometry::Vec3> p_a, p_b;
  for (const auto& [frame, T_a_board] : a.T_c_b) {
    const auto in_b = b.T_c_b.find(frame);
    if (in_b == b.T_c_b.end()) continue;
    for (const Observation* o : a.views.at(frame).points) {
      p_a.push_back(T_a_board * o->p_board);
      p_b.push_back(in_b->second * o->p_board);
    }
  }
  const std::vector<double> weights(p_a.size(), 1.0);
  geometry::Transform T_b_a = geometry::Transform::Identity();
  if (!pose::absolute_orientation(pose::PointsInBody{p_a}, pose::PointsInWorld{p_b}, weights,
                                  T_b_a))
    throw CalibrationError("cameras " + std::to_string(a.id) + " and " + std::to_string(b.id) +
                           ": their common views do not determine their relative pose");
  return T_b_a;
}

struct Link {
  size_t camera = 0, from = 0;  ///< camera's relative pose comes from `from`'s, linked before
};

/// A breadth-first walk from the reference over camera pairs with at least min_common views, in
/// the order the extrinsics are then initialised. A camera the walk does not reach is refused,
/// with its common-view counts; before any fit, so the refusal is immediate.
std::vector<Link> link_to_reference(const std::vector<CameraStart>& cams, int min_common) {
  std::vector<Link> order;
  std::vector<char> linked(cams.size(), 0);
  linked[0] = 1;
  std::queue<size_t> next;
  next.push(0);
  while (!next.empty()) {
    const size_t a = next.front();
    next.pop();
    for (size_t b = 0; b < cams.size(); ++b) {
      if (linked[b] || common_views(cams[a], cams[b]) < min_common) continue;
      order.push_back({b, a});
      linked[b] = 1;
      next.push(b);
    }
  }
  for (size_t b = 0; b < cams.size(); ++b) {
    if (linked[b]) continue;
    std::string counts;
    for (size_t a = 0; a < cams.size(); ++a)
      if (a != b)
        counts += (counts.empty() ? "" : ", ") + std::string("camera ") +
                  std::to_string(cams[a].id) + ": " +
                  std::to_string(common_views(cams[a], cams[b]));
    throw CalibrationError(
        "camera " + std::to_string(cams[b].id) +
        ": never seen together with the reference camera " + std::to_string(cams[0].id) +
        ", directly or through another camera (usable views in common: " + counts +
        "; need >= " + std::to_string(min_common) + " with a linked camera)");
  }
  return order;
}

/// T_c_r of every camera, chaining the relative poses along the links.
std::vector<geometry::Transform> extrinsics_start(const std::vector<CameraStart>& cams,
                                                  const std::vector<Link>& order) {
  std::vector<geometry::Transform> T_c_r(cams.size(), geometry::Transform::Identity());
  for (const Link& l : order)
    T_c_r[l.camera] = relative_pose(cams[l.from], cams[l.camera]) * T_c_r[l.from];
  return T_c_r;
}

PoseVector pose_vector(const geometry::Transform& T) {
  PoseVector p;
  p << geometry::rotvec_from_rotation(T.linear()), T.translation();
  return p;
}

/// Weighted residuals (projected - observed) / sigma of the views `which` (indices into views).
std::vector<std::vector<Eigen::Vector2d>> weighted_residuals(
    const std::vector<RigView>& views, const std::vector<size_t>& which,
    const std::vector<IntrinsicParameterMap>& maps, const RigState& state) {
  std::vector<std::vector<Eigen::Vector2d>> out;
  for (size_t i : which) {
    const auto c = static_cast<size_t>(views[i].camera);
    const camera::CameraModel model(maps[c].intrinsics(state.z[c].data()));
    const geometry::Transform T_c_b = rig_view_transform(state, views[i]);
    auto& r = out.emplace_back();
    for (const Observation* o : views[i].view.points) {
      const auto pixel = model.project_world(T_c_b, state.warp.apply(o->p_board));
      r.push_back(pixel ? Eigen::Vector2d((*pixel - o->pixel) / o->weighting_sigma_px())
                        : Eigen::Vector2d::Constant(INFINITY));
    }
  }
  return out;
}

/// The gate of the intrinsic fit, per camera (each camera's own robust residual scale).
std::vector<std::vector<char>> gate_per_camera(const std::vector<RigView>& views,
                                               const std::vector<IntrinsicParameterMap>& maps,
                                               const RigState& state, double false_alarm) {
  std::vector<std::vector<char>> used(views.size());
  for (size_t c = 0; c < maps.size(); ++c) {
    std::vector<size_t> which;
    for (size_t i = 0; i < views.size(); ++i)
      if (views[i].camera == static_cast<int>(c)) which.push_back(i);
    const auto gated = outlier_gate(weighted_residuals(views, which, maps, state), false_alarm);
    for (size_t j = 0; j < which.size(); ++j)
      used[which[j]] = gated[j];
  }
  return used;
}

struct RigProblem {
  std::vector<RigView> views;
  std::vector<IntrinsicParameterMap> maps;
  RigState state;
  std::vector<int> frames;
  std::string deflection_reason;
};

RigProblem build_problem(const std::vector<CameraStart>& cams,
                         const std::vector<geometry::Transform>& T_c_r,
                         const IntrinsicOptions& options) {
  RigProblem p;
  std::set<int> frames;
  for (const CameraStart& c : cams)
    for (const auto& [frame, T] : c.T_c_b)
      frames.insert(frame);
  p.frames.assign(frames.begin(), frames.end());
  std::map<int, int> board_of_frame;
  for (size_t f = 0; f < p.frames.size(); ++f)
    board_of_frame[p.frames[f]] = static_cast<int>(f);
  p.state.T_r_b.assign(p.frames.size(), PoseVector::Zero());
  std::vector<char> board_set(p.frames.size(), 0);
  for (size_t c = 0; c < cams.size(); ++c) {
    p.maps.emplace_back(options, cams[c].intrinsic.intrinsics);
    p.state.z.push_back(p.maps.back().free_values(cams[c].intrinsic.intrinsics));
    p.state.T_c_r.push_back(pose_vector(T_c_r[c]));
    for (const auto& [frame, T_c_b] : cams[c].T_c_b) {
      const int board = board_of_frame.at(frame);
      p.views.push_back({static_cast<int>(c), board, cams[c].views.at(frame)});
      // The board pose from the lowest camera that saw it (the reference when it did).
      if (board_set[static_cast<size_t>(board)]) continue;
      board_set[static_cast<size_t>(board)] = 1;
      p.state.T_r_b[static_cast<size_t>(board)] = pose_vector(T_c_r[c].inverse() * T_c_b);
    }
  }
  p.state.T_c_r[0].setZero();  // exactly the identity: S_r is camera 0's frame
  std::vector<BoardView> all;
  for (const RigView& v : p.views)
    all.push_back(v.view);
  p.deflection_reason = decide_deflection(all, options, p.state.warp, "rig: ");
  if (p.state.warp.fitted && cams[0].intrinsic.board_deflection.fitted)
    p.state.warp.c = cams[0].intrinsic.board_deflection.c_m;  // the reference camera's own fit
  return p;
}

/// Residuals, RMS per camera and view, the residual variance and the joint covariance.
RigResult summarise(const RigProblem& p, const std::vector<std::vector<char>>& used,
                    const std::vector<CameraStart>& cams) {
  RigResult out;
  out.frames = p.frames;
  for (const PoseVector& b : p.state.T_r_b)
    out.T_r_b.push_back(pose_transform(b));
  double chi2 = 0, ssr_px = 0;
  int free = 0;
  for (size_t c = 0; c < cams.size(); ++c) {
    RigCameraResult cam;
    cam.camera_id = cams[c].id;
    cam.intrinsics = p.maps[c].intrinsics(p.state.z[c].data());
    cam.T_c_r = pose_transform(p.state.T_c_r[c]);
    cam.start_rms_px = cams[c].intrinsic.rms_px;
    cam.views_skipped = cams[c].intrinsic.views_skipped;
    cam.common_views_with_reference = common_views(cams[0], cams[c]);
    std::vector<size_t> which;
    for (size_t i = 0; i < p.views.size(); ++i)
      if (p.views[i].camera == static_cast<int>(c)) which.push_back(i);
    const auto weighted = weighted_residuals(p.views, which, p.maps, p.state);
    double camera_ssr = 0;
    for (size_t j = 0; j < which.size(); ++j) {
      const RigView& rv = p.views[which[j]];
      RigViewResult v{rv.view.frame};
      double view_ssr = 0;
      for (size_t k = 0; k < rv.view.points.size(); ++k) {
        const Observation& o = *rv.view.points[k];
        const Eigen::Vector2d r_px = -weighted[j][k] * o.weighting_sigma_px();
        const bool ok = used[which[j]][k];
        cam.residuals.push_back({v.frame, o.point_id, r_px, !ok});
        if (!ok) {
          ++v.points_rejected;
          continue;
        }
        ++v.points_used;
        view_ssr += r_px.squaredNorm();
        chi2 += weighted[j][k].squaredNorm();
      }
      v.rms_px = v.points_used ? std::sqrt(view_ssr / v.points_used) : 0;
      camera_ssr += view_ssr;
      cam.points_used += v.points_used;
      cam.points_rejected += v.points_rejected;
      cam.views.push_back(v);
    }
    cam.rms_px = cam.points_used ? std::sqrt(camera_ssr / cam.points_used) : 0;
    ssr_px += camera_ssr;
    out.points_used += cam.points_used;
    out.points_rejected += cam.points_rejected;
    free += p.maps[c].size() + (c > 0 ? 6 : 0);
    out.cameras.push_back(std::move(cam));
  }
  out.free_parameters =
      free + 6 * static_cast<int>(p.frames.size()) + (p.state.warp.fitted ? 2 : 0);
  const int dof = 2 * out.points_used - out.free_parameters;
  if (dof <= 0)
    throw CalibrationError(std::to_string(out.points_used) + " points give " +
                           std::to_string(2 * out.points_used) + " residuals for " +
                           std::to_string(out.free_parameters) + " parameters: add views");
  out.rms_px = std::sqrt(ssr_px / out.points_used);
  const double variance = chi2 / dof;
  out.residual_sigma_px = std::sqrt(variance);
  const RigCovariance cov = rig_covariance(p.views, used, p.maps, p.state, p.frames, variance);
  out.joint_covariance = cov.joint;
  out.board_deflection = deflection_result(p.state.warp, cov.warp, p.deflection_reason);
  for (size_t c = 0; c < out.cameras.size(); ++c) {
    RigCameraResult& cam = out.cameras[c];
    const auto at = static_cast<Eigen::Index>(kRigBlockSize * c);
    cam.intrinsic_covariance =
        out.joint_covariance.block<camera::kNumIntrinsics, camera::kNumIntrinsics>(at, at);
    cam.extrinsic_covariance =
        out.joint_covariance.block<6, 6>(at + camera::kNumIntrinsics, at + camera::kNumIntrinsics);
    const geometry::Vec3 t = cam.T_c_r.translation();
    cam.baseline_m = t.norm();
    if (cam.baseline_m > 0) {
      const geometry::Vec3 u = t / cam.baseline_m;  // d|t|/dt
      cam.baseline_sigma_m =
          std::sqrt(u.dot(cam.extrinsic_covariance.bottomRightCorner<3, 3>() * u));
    }
  }
  return out;
}

}  // namespace

RigResult calibrate_rig(const ObservationSet& set, const RigOptions& options) {
  std::vector<CameraStart> cams = group_by_camera(set);
  if (cams.empty() || cams[0].id != 0)
    throw CalibrationError("camera 0 (the reference camera) has no observations");
  if (cams.size() < 2)
    throw CalibrationError(
        "a rig calibration needs observations of at least 2 cameras; the "
        "observations have camera 0 only");
  const std::vector<Link> order = link_to_reference(cams, std::max(options.min_common_views, 1));
  for (CameraStart& c : cams) {
    c.intrinsic = calibrate_intrinsics(set, c.id, options.intrinsic);  // names the camera
    for (const ViewResult& v : c.intrinsic.views)
      c.T_c_b[v.frame] = v.T_c_b;
    for (const SkippedView& v : c.intrinsic.views_skipped)  // no start pose: not in the rig
      c.views.erase(v.frame);
  }
  const auto T_c_r = extrinsics_start(cams, order);
  RigProblem p = build_problem(cams, T_c_r, options.intrinsic);

  std::vector<std::vector<char>> used = gate_per_camera(p.views, p.maps, p.state, 0);
  int iterations = 0;
  for (int round = 0; round < kMaxRejectionRounds; ++round) {
    try {
      iterations += refine_rig(p.views, used, p.maps, p.state);
    } catch (const CalibrationError& e) {
      throw CalibrationError(std::string("rig: ") + e.what());
    }
    auto next = gate_per_camera(p.views, p.maps, p.state, options.intrinsic.outlier_false_alarm);
    if (next == used) break;
    used = std::move(next);
  }
  RigResult out = summarise(p, used, cams);
  out.iterations = iterations;
  return out;
}

}  // namespace storetrack::calib
