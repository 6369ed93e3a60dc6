// Scenario files (JSON, common/sim/scenarios/*.json): everything the simulator models, with its
// parameters. Format documented in common/sim/README.md; SI units, frames of
// docs/conventions.md. Errors throw ScenarioError naming the file and the JSON field.
#pragma once

#include <array>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "storetrack/camera/camera_model.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/sim/render.hpp"
#include "storetrack/survey/survey.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::sim {

class ScenarioError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

enum class ScenarioKind { kStoreSeparation, kPendulum, kStatic, kScaleBars };
const char* to_string(ScenarioKind kind);

/// One camera of the rig, mounted in a pylon pod (rigid with the pylon).
/// A camera moving in its mount after it was calibrated (a shifted bracket, the ejector's
/// shock): from start_s its pose in the pylon frame is T_p_c Exp(f(t) (rotation, translation)),
/// camera frame, f rising linearly from 0 to 1 over ramp_s (0: a step). The calibration stays
/// the unmoved one (calibration health tests, docs/calibration-health.md).
struct CameraMotion {
  bool enabled = false;
  double start_s = 0;
  double ramp_s = 0;
  geometry::Vec3 rotation_rad = geometry::Vec3::Zero();   ///< rotation vector, camera frame
  geometry::Vec3 translation_m = geometry::Vec3::Zero();  ///< camera frame
  /// f(t): 0 before start_s, then linear over ramp_s up to 1.
  double fraction(double t) const;
};

struct CameraSetup {
  int camera_id = 0;
  int unit_id = 0;
  camera::Intrinsics intrinsics;               ///< TRUE intrinsics
  geometry::Vec3 position_p_m{0, 0, 0};        ///< optical centre in the pylon frame
  geometry::Vec3 look_at_p_m{0, 0, 1};         ///< point on the optical axis, pylon frame
  double roll_rad = 0;                         ///< rotation about the optical axis
  double trigger_latency_ns = 20000;           ///< TRUE trigger-edge-to-exposure-start latency
  double latency_calibration_sigma_ns = 1000;  ///< 1 sigma error of the calibrated latency
  double trigger_jitter_sigma_ns = 1000;       ///< per-exposure latency jitter, 1 sigma
  CameraMotion motion;                         ///< none unless the scenario gives "motion"
};

/// 1-sigma errors of the rig calibration (drawn once per Simulator for calibrated_rig()).
struct CalibrationErrorModel {
  double focal_px = 0.3;
  double principal_point_px = 0.2;
  double skew_px = 0.0;
  std::array<double, 8> distortion{2e-4, 2e-4, 2e-5, 2e-5, 0, 0, 0, 0};  ///< k1 k2 p1 p2 k3..k6
  double rotation_rad = 5e-5;   ///< per axis, left perturbation of T_c_w
  double translation_m = 1e-4;  ///< per axis
  /// The rig's registration to the world, ONE error shared by every camera (as a bundle
  /// adjustment + world registration leaves it): T_c_w <- T_c_w o (Exp(phi), rho), phi and rho
  /// per axis in the world frame. Nonzero: calibrated_rig() states the joint covariance with the
  /// cross-camera terms (calibration file version 2). 0: no shared error, no draw.
  double registration_rotation_rad = 0;
  double registration_translation_m = 0;
};

/// One sinusoidal mode of the pylon + pod vibration, applied in the pylon frame:
/// T_w_p(t) = T_w_p0 * Exp(rot(t), trans(t)), rot = amplitude_rot * sin(2 pi f t + phase).
struct VibrationMode {
  double frequency_hz = 30;
  geometry::Vec3 amplitude_rot_rad = geometry::Vec3::Zero();
  geometry::Vec3 amplitude_trans_m = geometry::Vec3::Zero();
};

/// Mark photometry and sensor; the spot model of render.hpp.
struct MarkOptics {
  SensorModel sensor;
  double psf_sigma_px = 0.8;
  double flux_ref_e = 120000;  ///< spot flux of a facing mark at reference_distance_m
  double reference_distance_m = 2.3;
  double flux_distance_exponent = 2;  ///< flux ~ (d_ref / d)^exponent * cos(incidence)
  double min_incidence_cos = 0.2;     ///< marks seen more obliquely are not detected
  /// Fast-mode centroid sigma = factor * Cramer-Rao bound of the rendered spot (a moment
  /// centroider is less efficient than the bound), floored at min_sigma_px.
  double centroid_sigma_factor = 1.5;
  double min_sigma_px = 0.01;
  double min_in_image_fraction = 0.5;  ///< a spot mostly outside the image is not detected
};

/// Store body for occlusion: a cylinder along the store x axis.
struct StoreShape {
  double radius_m = 0.15;
  double x_tail_m = -1.0, x_nose_m = 1.0;
};

/// Store separation in the pylon frame (docs/conventions.md: p = x fwd, y right, z down).
/// Before release_time_s the store sits at T_p_s0. During the ejector stroke it accelerates
/// uniformly along +z_p over ejector_stroke_m in ejector_duration_s, its angular rates ramp
/// linearly to rate_ypr; afterwards it moves with constant acceleration accel_p (gravity
/// relative to the 1-g aircraft, drag) and constant angular acceleration.
struct SeparationMotion {
  geometry::Transform T_p_s0 = geometry::Transform::Identity();
  double release_time_s = 0.02;
  double ejector_stroke_m = 0.10;
  double ejector_duration_s = 0.05;
  geometry::Vec3 accel_p_m_s2{-3.0, 0.0, 9.7864304};
  geometry::Vec3 rate_ypr_rad_s{0.05, 0.6, 0.1};  ///< yaw, pitch, roll rates after stroke
  geometry::Vec3 accel_ypr_rad_s2{0.1, 0.8, 0.0};
};

/// Pendulum board: m l2^2 theta'' + beta theta' + m g l1 sin(theta) = 0 (SisTrO dynamic
/// calibration, /work/shared/docs/method.md). theta = 0 hangs straight down; the board frame b
/// rotates by theta about the pivot axis (pointing towards the cameras).
struct PendulumMotion {
  double l1_m = 0.328, l2_m = 0.507, mass_kg = 0.0610;
  double damping_n_m_s = 2e-4;  ///< beta
  double g_m_s2 = 9.7864304;
  double theta0_rad = -185.614 * M_PI / 180;
  double theta_dot0_rad_s = 0;
  double release_time_s = 0.01;
  geometry::Vec3 pivot_p_m{-0.3, 0, 0.6};
  geometry::Vec3 axis_p{1, 0, -0.25};  ///< rotation axis (normalised on load), pylon frame
};

/// Scale bars at the VDI/VDE 2634-1 positions of a box-shaped measuring volume (pylon frame):
/// the 4 space diagonals and 3 axis-parallel lines through the centre, each spanning
/// `span_fraction` of the volume.
struct ScaleBarLayout {
  geometry::Vec3 centre_p_m{-0.3, 0, 0.7};
  geometry::Vec3 size_m{1.2, 0.8, 0.8};
  double span_fraction = 0.8;
  double mark_sigma_m = 3.5e-6;  ///< bar calibration, per end and axis
  double mark_diameter_m = 0.015;
};

struct Scenario {
  std::string origin;  ///< file it came from (error messages)
  std::string name;
  ScenarioKind kind = ScenarioKind::kStoreSeparation;
  double frame_rate_hz = 400;
  int num_exposures = 200;
  std::uint32_t exposure_ns = 500000;
  time::TaiNs start_tai_ns = 0;  ///< trigger time of exposure 0
  std::uint32_t first_trigger_seq = 0;
  double ptp_offset_sigma_ns = 200;  ///< per-unit TAI stamp error, 1 sigma
  time::ClockState clock_state = time::ClockState::kLocked;
  geometry::Transform T_w_p = geometry::Transform::Identity();  ///< nominal pylon pose
  std::vector<CameraSetup> cameras;
  CalibrationErrorModel calibration;
  std::vector<VibrationMode> vibration;
  MarkOptics optics;
  survey::RigidBodySurvey pylon;     ///< TRUE body coordinates; sigma_m drives survey errors
  survey::RigidBodySurvey store;     ///< (store separation and static scenarios)
  survey::RigidBodySurvey pendulum;  ///< (pendulum scenario)
  StoreShape store_shape;
  SeparationMotion separation;
  PendulumMotion pendulum_motion;
  ScaleBarLayout scale_bars;

  bool has_store() const {
    return kind == ScenarioKind::kStoreSeparation || kind == ScenarioKind::kStatic;
  }
};

Scenario load_scenario(const std::string& path);
Scenario parse_scenario(const std::string& json_text, const std::string& origin);

}  // namespace storetrack::sim
