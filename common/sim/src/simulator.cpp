#include "storetrack/sim/simulator.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <stdexcept>

namespace storetrack::sim {
namespace {

using geometry::Transform;
using geometry::Vec2;
using geometry::Vec3;

enum BodyKind { kPylon = 0, kStore = 1, kPendulum = 2, kScaleBar = 3 };

// Purposes of the random streams (stream_seed); 1-5 are the rig, timing, rendering and shared
// registration error of the constructor and the per-exposure draws.
constexpr std::uint64_t kFlightCentroidNoise = 4;
constexpr std::uint64_t kRegistrationSurveyNoise = 6;
constexpr std::uint64_t kRegistrationCentroidNoise = 7;
constexpr std::uint64_t kPooledBackgroundNoise = 8;
constexpr std::uint64_t kPooledSpotNoise = 9;
constexpr std::uint64_t kStoreCgNoise = 10;

// splitmix64 finaliser: independent, reproducible random streams per (purpose, k, camera).
std::uint64_t mix(std::uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

Transform look_at(const Vec3& position, const Vec3& target, double roll) {
  const Vec3 z = (target - position).normalized();
  Vec3 down(0, 0, 1);  // image rows increase towards z_p (down) before the roll
  if (std::abs(down.dot(z)) > 0.95) down = Vec3(-1, 0, 0);
  const Vec3 y = (down - down.dot(z) * z).normalized();
  const Vec3 x = y.cross(z);
  Transform T = Transform::Identity();
  T.linear().col(0) = x;
  T.linear().col(1) = y;
  T.linear().col(2) = z;
  T.linear() = T.linear() * Eigen::AngleAxisd(roll, Vec3::UnitZ()).toRotationMatrix();
  T.translation() = position;
  return T;
}

// Does the segment a -> b (store frame) pass through the solid store cylinder before b?
bool segment_hits_cylinder(const Vec3& a, const Vec3& b, const StoreShape& shape) {
  const Vec3 d = b - a;
  const double s_max = 1.0 - 1e-3;  // stop just short of the mark itself
  // Radial: |a_yz + s d_yz|^2 <= R^2.
  const double qa = d.y() * d.y() + d.z() * d.z();
  const double qb = 2 * (a.y() * d.y() + a.z() * d.z());
  const double qc = a.y() * a.y() + a.z() * a.z() - shape.radius_m * shape.radius_m;
  double r0, r1;
  if (qa < 1e-15) {
    if (qc > 0) return false;
    r0 = 0;
    r1 = s_max;
  } else {
    const double disc = qb * qb - 4 * qa * qc;
    if (disc <= 0) return false;
    const double sq = std::sqrt(disc);
    r0 = (-qb - sq) / (2 * qa);
    r1 = (-qb + sq) / (2 * qa);
  }
  // Axial: x_tail <= a.x + s d.x <= x_nose.
  double x0 = 0, x1 = s_max;
  if (std::abs(d.x()) < 1e-15) {
    if (a.x() < shape.x_tail_m || a.x() > shape.x_nose_m) return false;
  } else {
    double s0 = (shape.x_tail_m - a.x()) / d.x(), s1 = (shape.x_nose_m - a.x()) / d.x();
    if (s0 > s1) std::swap(s0, s1);
    x0 = std::max(x0, s0);
    x1 = std::min(x1, s1);
  }
  return std::max({r0, x0, 0.0}) < std::min({r1, x1, s_max});
}

}  // namespace

// The shared registration error: its own random stream, so scenarios without it draw exactly
// what they drew before. T_c_w o W = perturb_left(T_c_w, (R_c_w phi, R_c_w rho)) exactly, so the
// stated joint covariance is the cameras' blocks + D Sigma_reg D^T, D_c = diag(R_c_w, R_c_w).
void Simulator::draw_shared_registration_error() {
  const CalibrationErrorModel& ce = sc_.calibration;
  if (ce.registration_rotation_rad == 0 && ce.registration_translation_m == 0) return;
  std::mt19937_64 rng(stream_seed(5, 0, 0));
  std::normal_distribution<double> normal(0.0, 1.0);
  geometry::Vec6 sd;
  sd << Vec3::Constant(ce.registration_rotation_rad), Vec3::Constant(ce.registration_translation_m);
  geometry::Vec6 xi;
  for (int j = 0; j < 6; ++j)
    xi[j] = sd[j] * normal(rng);
  Transform W = Transform::Identity();
  W.linear() = geometry::rotation_from_rotvec(xi.head<3>());
  W.translation() = xi.tail<3>();
  constexpr int kB = camera::kJointBlockSize, kI = camera::kNumIntrinsics;
  const auto n = static_cast<Eigen::Index>(true_rig_.cameras.size());
  Eigen::MatrixXd D = Eigen::MatrixXd::Zero(kB * n, 6);
  for (Eigen::Index c = 0; c < n; ++c) {
    const geometry::Mat3 R = true_rig_.cameras[static_cast<size_t>(c)].T_c_w.linear();
    D.block<3, 3>(kB * c + kI, 0) = R;
    D.block<3, 3>(kB * c + kI + 3, 3) = R;
    // The camera's own error was drawn as a left perturbation of the true T_c_w; the shared
    // one acts on the world side (first order: the two perturbations add).
    camera::CalibratedCamera& cal = calibrated_rig_.cameras[static_cast<size_t>(c)];
    const geometry::Vec6 own =
        geometry::left_difference(cal.T_c_w, true_rig_.cameras[static_cast<size_t>(c)].T_c_w);
    cal.T_c_w = geometry::perturb_left(true_rig_.cameras[static_cast<size_t>(c)].T_c_w * W, own);
  }
  const Eigen::MatrixXd joint =
      true_rig_.full_joint_covariance() + D * sd.cwiseAbs2().asDiagonal() * D.transpose();
  camera::set_joint_covariance(true_rig_, joint);
  camera::set_joint_covariance(calibrated_rig_, joint);
}

std::uint64_t Simulator::stream_seed(std::uint64_t purpose, std::uint64_t a,
                                     std::uint64_t b) const {
  return mix(seed_ ^ mix(purpose * 0x100000001B3ull ^ mix(a * 0x9E3779B1ull + b)));
}

Simulator::Simulator(const Scenario& scenario, std::uint64_t seed)
    : sc_(scenario),
      seed_(seed),
      separation_(scenario.separation),
      pendulum_(scenario.pendulum_motion,
                scenario.num_exposures / std::max(scenario.frame_rate_hz, 1.0) + 1.0) {
  if (sc_.cameras.empty()) throw ScenarioError(sc_.origin + ": scenario has no cameras");
  if (sc_.frame_rate_hz <= 0) throw ScenarioError(sc_.origin + ": frame_rate_hz must be > 0");
  std::mt19937_64 rng(stream_seed(1, 0, 0));
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_real_distribution<double> uniform(0.0, 2 * M_PI);

  // Rig: truth and calibrated (truth + draws from the stated covariances).
  const CalibrationErrorModel& ce = sc_.calibration;
  camera::IntrinsicVector sig_in;
  sig_in << ce.focal_px, ce.focal_px, ce.principal_point_px, ce.principal_point_px, ce.skew_px,
      ce.distortion[0], ce.distortion[1], ce.distortion[2], ce.distortion[3], ce.distortion[4],
      ce.distortion[5], ce.distortion[6], ce.distortion[7];
  geometry::Vec6 sig_ex;
  sig_ex << ce.rotation_rad, ce.rotation_rad, ce.rotation_rad, ce.translation_m, ce.translation_m,
      ce.translation_m;
  std::map<int, double> unit_offsets;
  for (const CameraSetup& cs : sc_.cameras) {
    const Transform T_p_c = look_at(cs.position_p_m, cs.look_at_p_m, cs.roll_rad);
    T_p_c_.push_back(T_p_c);
    camera::CalibratedCamera cam;
    cam.camera_id = cs.camera_id;
    cam.unit_id = cs.unit_id;
    cam.model = camera::CameraModel(cs.intrinsics);
    cam.T_c_w = (sc_.T_w_p * T_p_c).inverse();
    cam.intrinsic_covariance = sig_in.cwiseAbs2().asDiagonal();
    cam.extrinsic_covariance = sig_ex.cwiseAbs2().asDiagonal();
    cam.exposure_offset_ns = cs.trigger_latency_ns;
    cam.exposure_offset_sigma_ns =
        std::hypot(cs.trigger_jitter_sigma_ns, cs.latency_calibration_sigma_ns);
    true_rig_.cameras.push_back(cam);

    camera::CalibratedCamera cal = cam;
    camera::IntrinsicVector v = camera::pack(cs.intrinsics);
    for (int j = 0; j < camera::kNumIntrinsics; ++j)
      v[j] += sig_in[j] * normal(rng);
    cal.model = camera::CameraModel(
        camera::unpack(v, cs.intrinsics.width, cs.intrinsics.height, cs.intrinsics.lens_model));
    geometry::Vec6 d;
    for (int j = 0; j < 6; ++j)
      d[j] = sig_ex[j] * normal(rng);
    cal.T_c_w = geometry::perturb_left(cam.T_c_w, d);
    cal.exposure_offset_ns = cs.trigger_latency_ns + cs.latency_calibration_sigma_ns * normal(rng);
    calibrated_rig_.cameras.push_back(cal);
    if (!unit_offsets.count(cs.unit_id)) {
      unit_offsets[cs.unit_id] = sc_.ptp_offset_sigma_ns * normal(rng);
    }
    unit_ptp_offset_ns_.push_back(unit_offsets[cs.unit_id]);
  }
  for (std::size_t m = 0; m < sc_.vibration.size(); ++m)
    vibration_phase_.push_back(uniform(rng));
  draw_shared_registration_error();

  // Surveys as measured: truth + N(0, sigma_m) per axis.
  const auto survey = [&](const survey::RigidBodySurvey& truth) {
    survey::RigidBodySurvey s = truth;
    for (survey::SurveyedMark& m : s.marks) {
      for (int a = 0; a < 3; ++a)
        m.p_body[a] += m.sigma_m * normal(rng);
    }
    return s;
  };
  pylon_surveyed_ = survey(sc_.pylon);
  bodies_.push_back({&sc_.pylon, kPylon, Transform::Identity()});
  if (sc_.has_store()) {
    store_surveyed_ = survey(sc_.store);
    // The CG (a mass-properties measurement, not the marks' survey) from its own stream: a
    // scenario without one draws exactly what it drew before.
    if (store_surveyed_.cg) {
      std::mt19937_64 cg_rng(stream_seed(kStoreCgNoise, 0, 0));
      std::normal_distribution<double> cg_normal;
      for (int a = 0; a < 3; ++a)
        store_surveyed_.cg->p_body[a] += store_surveyed_.cg->sigma_m * cg_normal(cg_rng);
    }
    bodies_.push_back({&sc_.store, kStore, Transform::Identity()});
  }
  if (sc_.kind == ScenarioKind::kPendulum) {
    pendulum_surveyed_ = survey(sc_.pendulum);
    bodies_.push_back({&sc_.pendulum, kPendulum, Transform::Identity()});
  }
  if (sc_.kind == ScenarioKind::kScaleBars) {
    // VDI/VDE 2634-1: 4 space diagonals + 3 axis-parallel lines through the volume centre.
    const ScaleBarLayout& L = sc_.scale_bars;
    const Vec3 h = 0.5 * L.span_fraction * L.size_m;
    const std::vector<std::pair<Vec3, Vec3>> ends = {
        {Vec3(-1, -1, -1), Vec3(1, 1, 1)}, {Vec3(1, -1, -1), Vec3(-1, 1, 1)},
        {Vec3(-1, 1, -1), Vec3(1, -1, 1)}, {Vec3(-1, -1, 1), Vec3(1, 1, -1)},
        {Vec3(-1, 0, 0), Vec3(1, 0, 0)},   {Vec3(0, -1, 0), Vec3(0, 1, 0)},
        {Vec3(0, 0, -1), Vec3(0, 0, 1)}};
    bars_true_.reserve(ends.size());
    std::vector<Transform> poses;
    for (std::size_t j = 0; j < ends.size(); ++j) {
      const Vec3 a = L.centre_p_m + ends[j].first.cwiseProduct(h);
      const Vec3 b = L.centre_p_m + ends[j].second.cwiseProduct(h);
      const Vec3 x = (b - a).normalized();
      Vec3 helper = std::abs(x.z()) < 0.9 ? Vec3::UnitZ() : Vec3::UnitX();
      const Vec3 y = helper.cross(x).normalized();
      Transform T = Transform::Identity();
      T.linear().col(0) = x;
      T.linear().col(1) = y;
      T.linear().col(2) = x.cross(y);
      T.translation() = a;
      poses.push_back(T);
      survey::RigidBodySurvey bar;
      bar.name = "scale_bar_" + std::to_string(j);
      bar.frame = 'b';
      bar.mark_diameter_m = L.mark_diameter_m;
      const int id0 = 300 + 2 * static_cast<int>(j);
      bar.marks.push_back({id0, Vec3::Zero(), L.mark_sigma_m});
      bar.marks.push_back({id0 + 1, Vec3((b - a).norm(), 0, 0), L.mark_sigma_m});
      bars_true_.push_back(bar);
    }
    for (std::size_t j = 0; j < bars_true_.size(); ++j) {
      bars_surveyed_.push_back(survey(bars_true_[j]));
      bodies_.push_back({&bars_true_[j], kScaleBar, poses[j]});
    }
  }
  for (std::size_t b = 0; b < bodies_.size(); ++b) {
    for (const survey::SurveyedMark& m : bodies_[b].survey->marks)
      marks_.push_back({m.id, b, m.p_body});
  }
  std::sort(marks_.begin(), marks_.end(),
            [](const MarkRef& a, const MarkRef& b) { return a.id < b.id; });
  for (std::size_t i = 0; i < marks_.size(); ++i) {
    if (i > 0 && marks_[i].id == marks_[i - 1].id) {
      throw ScenarioError(sc_.origin + ": mark id " + std::to_string(marks_[i].id) +
                          " used by two bodies");
    }
    mark_ids_.push_back(marks_[i].id);
  }
}

std::vector<survey::RigidBodySurvey> Simulator::surveys() const {
  std::vector<survey::RigidBodySurvey> out{pylon_surveyed_};
  if (sc_.has_store()) out.push_back(store_surveyed_);
  if (sc_.kind == ScenarioKind::kPendulum) out.push_back(pendulum_surveyed_);
  for (const survey::RigidBodySurvey& b : bars_surveyed_)
    out.push_back(b);
  return out;
}

survey::ScaleBarSet Simulator::scale_bar_set(bool truth) const {
  survey::ScaleBarSet set;
  set.name = sc_.name + (truth ? " (true lengths)" : " (as calibrated)");
  const std::vector<survey::RigidBodySurvey>& bars = truth ? bars_true_ : bars_surveyed_;
  for (const survey::RigidBodySurvey& b : bars) {
    survey::ScaleBar bar;
    bar.id = b.name;
    bar.mark_a = b.marks[0].id;
    bar.mark_b = b.marks[1].id;
    bar.length_m = (b.marks[1].p_body - b.marks[0].p_body).norm();
    bar.u_length_m = std::sqrt(2.0) * sc_.scale_bars.mark_sigma_m;
    set.bars.push_back(bar);
  }
  return set;
}

time::TaiNs Simulator::trigger_tai_ns(int k) const {
  return sc_.start_tai_ns + std::llround(k * 1e9 / sc_.frame_rate_hz);
}

double Simulator::seconds_since_start(time::TaiNs tai) const {
  return static_cast<double>(tai - sc_.start_tai_ns) * 1e-9;
}

namespace {
Transform vibration_at(const std::vector<VibrationMode>& modes, const std::vector<double>& phase,
                       double t) {
  Vec3 rot = Vec3::Zero(), trans = Vec3::Zero();
  for (std::size_t m = 0; m < modes.size(); ++m) {
    const double s = std::sin(2 * M_PI * modes[m].frequency_hz * t + phase[m]);
    rot += modes[m].amplitude_rot_rad * s;
    trans += modes[m].amplitude_trans_m * s;
  }
  return geometry::make_transform(rot, trans);
}
}  // namespace

Transform Simulator::T_w_p_at(time::TaiNs tai) const {
  return sc_.T_w_p * vibration_at(sc_.vibration, vibration_phase_, seconds_since_start(tai));
}

Transform Simulator::T_w0_w_at(time::TaiNs tai) const {
  return sc_.T_w_p * T_w_p_at(tai).inverse();
}

Transform Simulator::T_p_s_at(time::TaiNs tai) const {
  // The pendulum is the tracked body of its scenario: the host solves its pose as the "store".
  if (sc_.kind == ScenarioKind::kPendulum) return pendulum_.T_p_b(seconds_since_start(tai));
  if (!sc_.has_store()) return Transform::Identity();
  if (sc_.kind == ScenarioKind::kStatic) return sc_.separation.T_p_s0;
  return separation_.T_p_s(seconds_since_start(tai));
}

Transform Simulator::T_p_body(const Body& body, double t) const {
  switch (body.kind) {
    case kStore:
      return sc_.kind == ScenarioKind::kStatic ? sc_.separation.T_p_s0 : separation_.T_p_s(t);
    case kPendulum:
      return pendulum_.T_p_b(t);
    case kScaleBar:
      return body.T_p_b;
    default:
      return Transform::Identity();
  }
}

Vec3 Simulator::position_w(const MarkRef& m, double t) const {
  return sc_.T_w_p * vibration_at(sc_.vibration, vibration_phase_, t) *
         (T_p_body(bodies_[m.body], t) * m.p_body);
}

Vec3 Simulator::mark_position_w(int mark_id, time::TaiNs tai) const {
  for (const MarkRef& m : marks_) {
    if (m.id == mark_id) return position_w(m, seconds_since_start(tai));
  }
  throw std::out_of_range("Simulator: unknown mark id " + std::to_string(mark_id));
}

Transform Simulator::T_w_c_at(int camera_index, double t) const {
  const auto i = static_cast<std::size_t>(camera_index);
  const Transform T_w_c = sc_.T_w_p * vibration_at(sc_.vibration, vibration_phase_, t) * T_p_c_[i];
  const CameraMotion& motion = sc_.cameras[i].motion;
  const double f = motion.fraction(t);
  if (f == 0) return T_w_c;
  return T_w_c * geometry::make_transform(f * motion.rotation_rad, f * motion.translation_m);
}

Simulator::CameraTiming Simulator::timing(int k, int camera_index) const {
  const CameraSetup& cs = sc_.cameras[static_cast<std::size_t>(camera_index)];
  std::mt19937_64 rng(
      stream_seed(2, static_cast<std::uint64_t>(k), static_cast<std::uint64_t>(camera_index)));
  std::normal_distribution<double> normal(0.0, 1.0);
  const time::TaiNs trigger = trigger_tai_ns(k);
  CameraTiming t;
  t.true_start =
      trigger + std::llround(cs.trigger_latency_ns + cs.trigger_jitter_sigma_ns * normal(rng));
  t.reported_start =
      trigger + std::llround(unit_ptp_offset_ns_[static_cast<std::size_t>(camera_index)]);
  return t;
}

MarkCameraTruth Simulator::see(const MarkRef& m, int camera_index, double t_start,
                               double t_end) const {
  MarkCameraTruth out;
  const camera::CalibratedCamera& cam = true_rig_.cameras[static_cast<std::size_t>(camera_index)];
  const camera::Intrinsics& in = cam.model.intrinsics();
  const double t_mid = 0.5 * (t_start + t_end);
  const Transform T_w_c = T_w_c_at(camera_index, t_mid);
  const Transform T_c_w = T_w_c.inverse();
  const Vec3 p_w = position_w(m, t_mid);
  const Vec3 p_c = T_c_w * p_w;
  // Field-of-view guard: beyond it the polynomial distortion may fold points back inside.
  const auto in_fov = [](const Vec3& p) {
    return p.z() > 0.05 && std::abs(p.x() / p.z()) < 2.0 && std::abs(p.y() / p.z()) < 2.0;
  };
  if (!in_fov(p_c)) return out;
  const auto pix = cam.model.project(p_c);
  if (!pix) return out;
  out.in_front = true;
  out.pixel = *pix;
  out.in_image = pix->x() >= -0.5 && pix->x() <= in.width - 0.5 && pix->y() >= -0.5 &&
                 pix->y() <= in.height - 0.5;
  const Vec3 p_c0 = T_w_c_at(camera_index, t_start).inverse() * position_w(m, t_start);
  const Vec3 p_c1 = T_w_c_at(camera_index, t_end).inverse() * position_w(m, t_end);
  if (in_fov(p_c0) && in_fov(p_c1)) {
    const auto u0 = cam.model.project(p_c0), u1 = cam.model.project(p_c1);
    if (u0 && u1) out.blur_px = *u1 - *u0;
  }
  // Incidence: store marks face radially out of the cylinder; pendulum marks along the board
  // normal (pivot axis); pylon and scale-bar marks are mounted facing the cameras.
  const Body& body = bodies_[m.body];
  const Vec3 to_cam = (T_w_c.translation() - p_w).normalized();
  double cos_inc = 1.0;
  const Transform T_w_b =
      sc_.T_w_p * vibration_at(sc_.vibration, vibration_phase_, t_mid) * T_p_body(body, t_mid);
  if (body.kind == kStore) {
    Vec3 n_s(0, m.p_body.y(), m.p_body.z());
    if (n_s.norm() > 1e-9) cos_inc = (T_w_b.linear() * n_s.normalized()).dot(to_cam);
  } else if (body.kind == kPendulum) {
    cos_inc = std::abs((T_w_b.linear() * Vec3::UnitZ()).dot(to_cam));
  }
  out.facing = cos_inc >= sc_.optics.min_incidence_cos;
  if (sc_.has_store() && body.kind != kStore) {
    const Transform T_s_w = (sc_.T_w_p * vibration_at(sc_.vibration, vibration_phase_, t_mid) *
                             T_p_body(bodies_[1], t_mid))
                                .inverse();
    out.occluded = segment_hits_cylinder(T_s_w * T_w_c.translation(), T_s_w * p_w, sc_.store_shape);
  }
  out.visible = out.in_front && out.in_image && out.facing && !out.occluded;
  const double dist = (T_w_c.translation() - p_w).norm();
  const double c = std::max(cos_inc, 0.0);
  // Area-equivalent diameter of the foreshortened disc.
  out.disc_diameter_px =
      body.survey->mark_diameter_m * 0.5 * (in.fx + in.fy) / p_c.z() * std::sqrt(c);
  out.flux_e = sc_.optics.flux_ref_e *
               std::pow(sc_.optics.reference_distance_m / dist, sc_.optics.flux_distance_exponent) *
               c;
  return out;
}

ExposureTruth Simulator::truth(int k) const {
  ExposureTruth tr;
  tr.trigger_seq = sc_.first_trigger_seq + static_cast<std::uint32_t>(k);
  tr.trigger_tai_ns = trigger_tai_ns(k);
  tr.reference_tai_ns =
      tr.trigger_tai_ns + std::llround(sc_.cameras[0].trigger_latency_ns) + sc_.exposure_ns / 2;
  tr.T_w_p = T_w_p_at(tr.reference_tai_ns);
  tr.T_p_s = T_p_s_at(tr.reference_tai_ns);
  std::vector<std::pair<double, double>> windows;
  for (int i = 0; i < num_cameras(); ++i) {
    const CameraTiming ct = timing(k, i);
    CameraExposureTruth c;
    c.camera_id = sc_.cameras[static_cast<std::size_t>(i)].camera_id;
    c.exposure_start_tai_ns = ct.true_start;
    c.reported_start_tai_ns = ct.reported_start;
    c.exposure_ns = sc_.exposure_ns;
    const double t0 = seconds_since_start(ct.true_start);
    const double t1 = t0 + sc_.exposure_ns * 1e-9;
    c.T_w_c = T_w_c_at(i, 0.5 * (t0 + t1));
    tr.cameras.push_back(c);
    windows.emplace_back(t0, t1);
  }
  const double t_ref = seconds_since_start(tr.reference_tai_ns);
  constexpr double kDt = 1e-5;
  const Transform T_w0_w = T_w0_w_at(tr.reference_tai_ns);
  for (const MarkRef& m : marks_) {
    MarkTruth mt;
    mt.id = m.id;
    mt.p_w = position_w(m, t_ref);
    mt.p_w0 = T_w0_w * mt.p_w;
    mt.v_w = (position_w(m, t_ref + kDt) - position_w(m, t_ref - kDt)) / (2 * kDt);
    for (int i = 0; i < num_cameras(); ++i) {
      const auto& w = windows[static_cast<std::size_t>(i)];
      mt.cameras.push_back(see(m, i, w.first, w.second));
    }
    tr.marks.push_back(std::move(mt));
  }
  return tr;
}

void Simulator::spots(int k, int camera_index, std::vector<Spot>& out,
                      std::vector<int>* mark_ids) const {
  out.clear();
  if (mark_ids) mark_ids->clear();
  const CameraTiming ct = timing(k, camera_index);
  const double t0 = seconds_since_start(ct.true_start);
  const double t1 = t0 + sc_.exposure_ns * 1e-9;
  const camera::Intrinsics& in =
      true_rig_.cameras[static_cast<std::size_t>(camera_index)].model.intrinsics();
  for (const MarkRef& m : marks_) {
    const MarkCameraTruth mc = see(m, camera_index, t0, t1);
    if (!mc.in_front || !mc.facing || mc.occluded) continue;
    Spot s;
    s.x_px = mc.pixel.x();
    s.y_px = mc.pixel.y();
    s.psf_sigma_px = sc_.optics.psf_sigma_px;
    s.disc_diameter_px = mc.disc_diameter_px;
    s.flux_e = mc.flux_e;
    s.blur_dx_px = mc.blur_px.x();
    s.blur_dy_px = mc.blur_px.y();
    if (spot_box(s, in.width, in.height).empty()) continue;
    out.push_back(s);
    if (mark_ids) mark_ids->push_back(m.id);
  }
}

void Simulator::render_into(int k, int camera_index, std::uint8_t* image, int stride,
                            SpotRenderer& renderer) const {
  thread_local std::vector<Spot> spot_list;
  spots(k, camera_index, spot_list);
  const camera::Intrinsics& in =
      true_rig_.cameras[static_cast<std::size_t>(camera_index)].model.intrinsics();
  std::mt19937_64 rng(
      stream_seed(3, static_cast<std::uint64_t>(k), static_cast<std::uint64_t>(camera_index)));
  renderer.render(spot_list, sc_.optics.sensor, rng, image, in.width, in.height, stride);
}

void Simulator::render_background_into(int pool_index, int camera_index, std::uint8_t* image,
                                       int stride, SpotRenderer& renderer) const {
  const camera::Intrinsics& in =
      true_rig_.cameras[static_cast<std::size_t>(camera_index)].model.intrinsics();
  std::mt19937_64 rng(stream_seed(kPooledBackgroundNoise, static_cast<std::uint64_t>(pool_index),
                                  static_cast<std::uint64_t>(camera_index)));
  renderer.render_background(sc_.optics.sensor, rng, image, in.width, in.height, stride);
}

void Simulator::render_spots_into(int k, int camera_index, std::uint8_t* image, int stride,
                                  SpotRenderer& renderer,
                                  std::span<const float> unit_normals) const {
  thread_local std::vector<Spot> spot_list;
  spots(k, camera_index, spot_list);
  const camera::Intrinsics& in =
      true_rig_.cameras[static_cast<std::size_t>(camera_index)].model.intrinsics();
  std::mt19937_64 rng(stream_seed(kPooledSpotNoise, static_cast<std::uint64_t>(k),
                                  static_cast<std::uint64_t>(camera_index)));
  if (!unit_normals.empty()) {
    renderer.render_spots_gaussian(spot_list, sc_.optics.sensor, unit_normals,
                                   static_cast<std::size_t>(rng() % unit_normals.size()), image,
                                   in.width, in.height, stride);
    return;
  }
  renderer.render_spots(spot_list, sc_.optics.sensor, rng, image, in.width, in.height, stride);
}

void Simulator::render(int k, int camera_index, std::vector<std::uint8_t>& image) const {
  const camera::Intrinsics& in =
      true_rig_.cameras[static_cast<std::size_t>(camera_index)].model.intrinsics();
  image.resize(static_cast<std::size_t>(in.width) * in.height);
  thread_local SpotRenderer renderer;
  render_into(k, camera_index, image.data(), in.width, renderer);
}

ExposureTiming Simulator::exposure_timing(int k, int camera_index) const {
  const CameraTiming ct = timing(k, camera_index);
  ExposureTiming t;
  t.trigger_seq = sc_.first_trigger_seq + static_cast<std::uint32_t>(k);
  t.trigger_tai_ns = trigger_tai_ns(k);
  t.true_start_tai_ns = ct.true_start;
  t.reported_start_tai_ns = ct.reported_start;
  t.reported_start_mono_ns = ct.reported_start - sc_.start_tai_ns + 1000 * time::kNsPerSecond;
  t.exposure_ns = sc_.exposure_ns;
  return t;
}

void Simulator::observe(int k, int camera_index, msg::MarkObservations& out,
                        std::vector<int>* true_mark_ids) const {
  observe_with_noise(k, camera_index, kFlightCentroidNoise, out, true_mark_ids);
}

void Simulator::observe_registration(int camera_index, msg::MarkObservations& out,
                                     std::vector<int>* true_mark_ids) const {
  std::vector<int> ids;
  observe_with_noise(0, camera_index, kRegistrationCentroidNoise, out, &ids);
  // Only the surveyed registration marks (the pylon's): a blob of another body, or merged with
  // one (id -1), is not a registration mark.
  if (true_mark_ids) true_mark_ids->clear();
  std::size_t kept = 0;
  for (std::size_t i = 0; i < out.mark_count; ++i) {
    if (sc_.pylon.find(ids[i]) == nullptr) continue;
    out.marks[kept++] = out.marks[i];
    if (true_mark_ids) true_mark_ids->push_back(ids[i]);
  }
  out.mark_count = static_cast<std::uint8_t>(kept);
}

std::vector<RegistrationSighting> Simulator::registration_sightings() const {
  std::vector<RegistrationSighting> out;
  msg::MarkObservations obs;
  std::vector<int> ids;
  for (int c = 0; c < num_cameras(); ++c) {
    observe_registration(c, obs, &ids);
    for (std::size_t i = 0; i < obs.mark_count; ++i) {
      const msg::MarkObservation& m = obs.marks[i];
      if (m.flags & (msg::mark_flags::kBorder | msg::mark_flags::kMerged)) continue;
      out.push_back({obs.camera_id, ids[i], geometry::Vec2(m.x_px, m.y_px), m.sigma_px});
    }
  }
  return out;
}

survey::RigidBodySurvey Simulator::registration_survey(bool truth) const {
  survey::RigidBodySurvey s = sc_.pylon;
  s.name = "aircraft";
  s.frame = 'w';
  std::mt19937_64 rng(stream_seed(kRegistrationSurveyNoise, 0, 0));
  std::normal_distribution<double> normal(0.0, 1.0);
  for (survey::SurveyedMark& m : s.marks) {
    m.p_body = sc_.T_w_p * m.p_body;
    if (truth) continue;
    for (int a = 0; a < 3; ++a)
      m.p_body[a] += m.sigma_m * normal(rng);
  }
  return s;
}

void Simulator::observe_with_noise(int k, int camera_index, std::uint64_t noise_purpose,
                                   msg::MarkObservations& out,
                                   std::vector<int>* true_mark_ids) const {
  const CameraSetup& cs = sc_.cameras[static_cast<std::size_t>(camera_index)];
  const camera::Intrinsics& in =
      true_rig_.cameras[static_cast<std::size_t>(camera_index)].model.intrinsics();
  const MarkOptics& op = sc_.optics;
  const ExposureTiming et = exposure_timing(k, camera_index);
  out = msg::MarkObservations{};
  out.unit_id = static_cast<std::uint8_t>(cs.unit_id);
  out.camera_id = static_cast<std::uint8_t>(cs.camera_id);
  out.trigger_seq = sc_.first_trigger_seq + static_cast<std::uint32_t>(k);
  out.exposure_start_tai_ns = et.reported_start_tai_ns;
  out.exposure_start_mono_ns = et.reported_start_mono_ns;
  out.exposure_duration_ns = sc_.exposure_ns;
  out.clock_state = static_cast<std::uint8_t>(sc_.clock_state);
  // The unit's stamp error is drawn from N(0, ptp_offset_sigma_ns) (timing()): its stated figure.
  out.exposure_time_sigma_ns = static_cast<std::uint32_t>(std::lround(sc_.ptp_offset_sigma_ns));
  if (true_mark_ids) true_mark_ids->clear();

  struct Detection {
    double x, y, sigma, peak_e, flux, diameter, psf;
    std::uint8_t flags;
    int id;
  };
  thread_local std::vector<Spot> spot_list;
  thread_local std::vector<int> ids;
  thread_local std::vector<Detection> dets;
  spots(k, camera_index, spot_list, &ids);
  dets.clear();
  for (std::size_t j = 0; j < spot_list.size(); ++j) {
    const Spot& s = spot_list[j];
    const SpotStatistics st = spot_statistics(s, op.sensor, in.width, in.height);
    if (st.in_image_fraction < op.min_in_image_fraction) continue;
    const double blur = std::hypot(s.blur_dx_px, s.blur_dy_px);
    const double reach = s.disc_diameter_px / 2 + blur / 2 + 2 * s.psf_sigma_px;
    const bool border = s.x_px - reach < 0 || s.x_px + reach > in.width - 1 || s.y_px - reach < 0 ||
                        s.y_px + reach > in.height - 1;
    Detection d;
    d.x = border ? st.centroid_x_px : s.x_px;
    d.y = border ? st.centroid_y_px : s.y_px;
    d.sigma = std::max(op.centroid_sigma_factor * st.sigma_px, op.min_sigma_px);
    d.peak_e = st.peak_signal_e;
    d.flux = s.flux_e * st.in_image_fraction;
    // Area-equivalent diameter of the swept disc (pi D^2 / 4 + D L).
    d.diameter =
        std::sqrt(s.disc_diameter_px * s.disc_diameter_px + 4 / M_PI * s.disc_diameter_px * blur);
    d.psf = s.psf_sigma_px;
    d.flags = 0;
    if (st.saturated) d.flags |= msg::mark_flags::kSaturated;
    if (border) d.flags |= msg::mark_flags::kBorder;
    // Second-moment axis ratio of disc (*) segment (*) PSF.
    const double minor2 = s.disc_diameter_px * s.disc_diameter_px / 16 + d.psf * d.psf;
    if (std::sqrt((minor2 + blur * blur / 12) / minor2) > 1.5) {
      d.flags |= msg::mark_flags::kElongated;
    }
    d.id = ids[j];
    dets.push_back(d);
  }
  // Touching spots merge into one blob at the flux-weighted centroid (as a centroider sees it).
  for (std::size_t a = 0; a < dets.size(); ++a) {
    for (std::size_t b = a + 1; b < dets.size();) {
      const double gap = (dets[a].diameter + dets[b].diameter) / 2 + 3 * dets[a].psf;
      if (std::hypot(dets[a].x - dets[b].x, dets[a].y - dets[b].y) < gap) {
        Detection& m = dets[a];
        const double f = m.flux + dets[b].flux;
        m.x = (m.x * m.flux + dets[b].x * dets[b].flux) / f;
        m.y = (m.y * m.flux + dets[b].y * dets[b].flux) / f;
        m.sigma = std::max(m.sigma, dets[b].sigma);
        m.peak_e = std::max(m.peak_e, dets[b].peak_e);
        m.diameter = std::sqrt(m.diameter * m.diameter + dets[b].diameter * dets[b].diameter);
        m.flux = f;
        m.flags |= dets[b].flags | msg::mark_flags::kMerged;
        m.id = -1;
        dets.erase(dets.begin() + static_cast<std::ptrdiff_t>(b));
        b = a + 1;
      } else {
        ++b;
      }
    }
  }
  // Raster order, as a centroider emits them.
  std::sort(dets.begin(), dets.end(), [](const Detection& a, const Detection& b) {
    return std::lround(a.y) != std::lround(b.y) ? a.y < b.y : a.x < b.x;
  });
  std::mt19937_64 rng(stream_seed(noise_purpose, static_cast<std::uint64_t>(k),
                                  static_cast<std::uint64_t>(camera_index)));
  std::normal_distribution<double> normal(0.0, 1.0);
  std::size_t n = 0;
  for (const Detection& d : dets) {
    const double nx = normal(rng), ny = normal(rng);
    if (n == msg::kMaxMarks) {
      out.flags |= msg::exposure_flags::kMarksTruncated;
      break;
    }
    msg::MarkObservation& o = out.marks[n++];
    o.x_px = static_cast<float>(std::clamp(d.x + d.sigma * nx, -0.5, in.width - 0.5));
    o.y_px = static_cast<float>(std::clamp(d.y + d.sigma * ny, -0.5, in.height - 0.5));
    o.sigma_px = static_cast<float>(d.sigma);
    o.peak = static_cast<std::uint16_t>(
        std::clamp(std::lround(d.peak_e / op.sensor.gain_e_per_dn), 1L, 255L));
    o.diameter_px = static_cast<float>(std::min(d.diameter, 31.5));
    o.flags = d.flags;
    if (true_mark_ids) true_mark_ids->push_back(d.id);
  }
  out.mark_count = static_cast<std::uint8_t>(n);
}

void write_truth_csv(const Simulator& sim, const std::string& poses_path,
                     const std::string& marks_path) {
  std::ofstream poses(poses_path), marks(marks_path);
  if (!poses) throw std::runtime_error(poses_path + ": cannot open for writing");
  if (!marks) throw std::runtime_error(marks_path + ": cannot open for writing");
  poses.precision(12);
  marks.precision(12);
  const auto pose_cols = [](std::ostream& os, const std::string& name) {
    for (const char* c :
         {"x_m", "y_m", "z_m", "yaw_rad", "pitch_rad", "roll_rad", "rx_rad", "ry_rad", "rz_rad"}) {
      os << "," << name << "_" << c;
    }
  };
  const auto pose_vals = [](std::ostream& os, const geometry::Transform& T) {
    const Vec3 ypr = geometry::ypr_from_rotation(T.linear());
    const Vec3 rv = geometry::rotvec_from_rotation(T.linear());
    os << "," << T.translation().x() << "," << T.translation().y() << "," << T.translation().z()
       << "," << ypr[0] << "," << ypr[1] << "," << ypr[2] << "," << rv[0] << "," << rv[1] << ","
       << rv[2];
  };
  poses << "trigger_seq,trigger_tai_ns,reference_tai_ns";
  pose_cols(poses, "T_w_p");
  pose_cols(poses, "T_p_s");
  for (const CameraSetup& c : sim.scenario().cameras) {
    poses << ",cam" << c.camera_id << "_true_exposure_start_tai_ns,cam" << c.camera_id
          << "_reported_exposure_start_tai_ns,cam" << c.camera_id << "_exposure_ns";
  }
  poses << "\n";
  marks << "trigger_seq,reference_tai_ns,mark_id,x_w_m,y_w_m,z_w_m,vx_w_m_s,vy_w_m_s,vz_w_m_s,"
           "x_w0_m,y_w0_m,z_w0_m";
  for (const CameraSetup& c : sim.scenario().cameras) {
    const std::string p = ",cam" + std::to_string(c.camera_id) + "_";
    marks << p << "visible" << p << "u_px" << p << "v_px" << p << "blur_du_px" << p << "blur_dv_px";
  }
  marks << "\n";
  for (int k = 0; k < sim.num_exposures(); ++k) {
    const ExposureTruth tr = sim.truth(k);
    poses << tr.trigger_seq << "," << tr.trigger_tai_ns << "," << tr.reference_tai_ns;
    pose_vals(poses, tr.T_w_p);
    pose_vals(poses, tr.T_p_s);
    for (const CameraExposureTruth& c : tr.cameras) {
      poses << "," << c.exposure_start_tai_ns << "," << c.reported_start_tai_ns << ","
            << c.exposure_ns;
    }
    poses << "\n";
    for (const MarkTruth& m : tr.marks) {
      marks << tr.trigger_seq << "," << tr.reference_tai_ns << "," << m.id << "," << m.p_w.x()
            << "," << m.p_w.y() << "," << m.p_w.z() << "," << m.v_w.x() << "," << m.v_w.y() << ","
            << m.v_w.z() << "," << m.p_w0.x() << "," << m.p_w0.y() << "," << m.p_w0.z();
      for (const MarkCameraTruth& c : m.cameras) {
        marks << "," << (c.visible ? 1 : 0) << "," << c.pixel.x() << "," << c.pixel.y() << ","
              << c.blur_px.x() << "," << c.blur_px.y();
      }
      marks << "\n";
    }
  }
  if (!poses || !marks) throw std::runtime_error("write_truth_csv: write failed");
}

}  // namespace storetrack::sim
