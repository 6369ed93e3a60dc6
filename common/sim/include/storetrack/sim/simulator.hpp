// The scene simulator: truth for every test and the no-hardware default.
//
// Timing model (per exposure k, camera i), all TAI ns:
//   trigger_k        = start_tai_ns + k / frame_rate            (shared trigger edge)
//   true start       = trigger_k + latency_i(true) + jitter_ik  (jitter ~ N(0, sigma_i))
//   reported start   = trigger_k + ptp_offset_unit              (what the unit stamps: the
//                      trigger edge on its PTP clock; MarkObservations.exposure_start_tai_ns)
// The calibrated rig carries exposure_offset_ns = latency_i + calibration error and
// exposure_offset_sigma_ns = sqrt(jitter^2 + calibration^2): the host estimates the true
// exposure start as reported start + exposure_offset_ns. Marks are imaged at the TRUE time, so
// synchronisation errors enter the observations as mark motion.
//
// Pylon and pods (cameras) vibrate together: T_w_p(t) = T_w_p0 Exp(v(t)), T_w_c(t) =
// T_w_p(t) T_p_c. Calibrated extrinsics are the static T_c_w0 (+ calibration error).
#pragma once

#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/sim/render.hpp"
#include "storetrack/sim/scenario.hpp"
#include "storetrack/sim/trajectory.hpp"
#include "storetrack/survey/scale_bars.hpp"
#include "storetrack/survey/survey.hpp"

namespace storetrack::sim {

/// One mark as seen by one camera in one exposure.
struct MarkCameraTruth {
  bool in_front = false;  ///< in front of the camera and inside the modelled field of view
  bool in_image = false;  ///< spot centre inside the image
  bool occluded = false;  ///< hidden by the store body
  bool facing = false;    ///< incidence within optics.min_incidence_cos
  bool visible = false;   ///< in_front && in_image && !occluded && facing
  geometry::Vec2 pixel = geometry::Vec2::Zero();    ///< projection at true mid-exposure [px]
  geometry::Vec2 blur_px = geometry::Vec2::Zero();  ///< image motion over the exposure [px]
  double disc_diameter_px = 0;
  double flux_e = 0;
};

struct MarkTruth {
  int id = 0;
  geometry::Vec3 p_w = geometry::Vec3::Zero();  ///< at the exposure's reference time
  geometry::Vec3 v_w = geometry::Vec3::Zero();  ///< velocity [m/s], world frame
  /// Position in the world frame as the rig realises it (w0): the cameras ride on the pylon
  /// pod and were registered at rest, so the host, seeing through static extrinsics, measures
  /// T_w_p0 T_w_p(t)^-1 p_w(t) (pod vibration cancels). What host mark positions are scored on.
  geometry::Vec3 p_w0 = geometry::Vec3::Zero();
  std::vector<MarkCameraTruth> cameras;  ///< per camera index
};

struct CameraExposureTruth {
  int camera_id = 0;
  time::TaiNs exposure_start_tai_ns = 0;  ///< TRUE exposure start
  time::TaiNs reported_start_tai_ns = 0;  ///< as stamped by the unit (see header comment)
  std::uint32_t exposure_ns = 0;
  geometry::Transform T_w_c = geometry::Transform::Identity();  ///< at true mid-exposure
};

struct ExposureTruth {
  std::uint32_t trigger_seq = 0;
  time::TaiNs trigger_tai_ns = 0;
  /// Reference instant of this truth: trigger + camera 0's true latency + exposure / 2.
  time::TaiNs reference_tai_ns = 0;
  geometry::Transform T_w_p = geometry::Transform::Identity();  ///< at reference time
  geometry::Transform T_p_s =
      geometry::Transform::Identity();  ///< tracked body: store or pendulum (identity if none)
  std::vector<CameraExposureTruth> cameras;
  std::vector<MarkTruth> marks;  ///< every mark of the scene, ascending id
};

/// Timing of one exposure of one camera (see the header comment).
/// One usable hangar sighting of a registration mark (storetrack-calib register's
/// registration_marks.csv row): neither cut by the image border nor merged with another blob.
struct RegistrationSighting {
  int camera_id = -1;
  int mark_id = -1;  ///< the mark's survey id
  geometry::Vec2 px = geometry::Vec2::Zero();
  double sigma_px = 0;
};

struct ExposureTiming {
  std::uint32_t trigger_seq = 0;
  time::TaiNs trigger_tai_ns = 0;
  time::TaiNs true_start_tai_ns = 0;
  time::TaiNs reported_start_tai_ns = 0;         ///< MarkObservations.exposure_start_tai_ns
  time::MonotonicNs reported_start_mono_ns = 0;  ///< the unit booted 1000 s before trigger 0
  std::uint32_t exposure_ns = 0;
};

class Simulator {
 public:
  Simulator(const Scenario& scenario, std::uint64_t seed);

  const Scenario& scenario() const { return sc_; }
  int num_exposures() const { return sc_.num_exposures; }
  int num_cameras() const { return static_cast<int>(sc_.cameras.size()); }

  const camera::RigCalibration& true_rig() const { return true_rig_; }
  /// Truth + errors drawn (once per seed) from the stated calibration covariances.
  camera::RigCalibration calibrated_rig() const { return calibrated_rig_; }

  /// Surveys as measured (truth + survey errors drawn with each mark's sigma_m).
  const survey::RigidBodySurvey& pylon_survey() const { return pylon_surveyed_; }
  const survey::RigidBodySurvey& store_survey() const { return store_surveyed_; }
  const survey::RigidBodySurvey& pendulum_survey() const { return pendulum_surveyed_; }
  const std::vector<survey::RigidBodySurvey>& scale_bar_surveys() const { return bars_surveyed_; }
  /// The scale bars as a calibration laboratory certifies them (VDI/VDE 2634-1; empty outside
  /// the scale_bars scenario): the true centre distance of each bar's two marks (`truth`) or
  /// the one of the surveyed marks (as calibrated: truth + survey error); u_length_m =
  /// sqrt(2) mark_sigma_m, the per-axis survey sigma of both marks along the bar.
  survey::ScaleBarSet scale_bar_set(bool truth) const;
  /// All surveys (as measured) present in this scenario.
  std::vector<survey::RigidBodySurvey> surveys() const;
  /// True body coordinates.
  const survey::RigidBodySurvey& true_pylon() const { return sc_.pylon; }

  /// The world registration's survey (storetrack-calib register, docs/calibration.md): the
  /// pylon marks as a total station surveys them in the aircraft frame S_w in the hangar, at the
  /// pylon's nominal pose (frame 'w', name "aircraft"), each with the pylon survey's sigma_m.
  /// `truth`: T_w_p0 p_p; else truth + N(0, sigma_m^2 I) from its own random stream (independent
  /// of the pylon survey in S_p, a separate session; other draws unchanged).
  survey::RigidBodySurvey registration_survey(bool truth) const;
  /// The registration marks as a unit centroids them in the hangar: the scene of exposure 0
  /// (store mounted, at rest) with centroid noise from its own stream, so no flight exposure
  /// shares it. Same fields and flags as observe().
  void observe_registration(int camera_index, msg::MarkObservations& out,
                            std::vector<int>* true_mark_ids = nullptr) const;
  /// observe_registration() of every camera without the blobs a registration cannot use
  /// (border-cut or merged: their centroid is not the mark's).
  std::vector<RegistrationSighting> registration_sightings() const;
  const survey::RigidBodySurvey& true_store() const { return sc_.store; }

  time::TaiNs trigger_tai_ns(int k) const;
  ExposureTiming exposure_timing(int k, int camera_index) const;
  double seconds_since_start(time::TaiNs tai) const;
  /// Truth at any instant (TAI ns).
  geometry::Transform T_w_p_at(time::TaiNs tai) const;
  geometry::Transform T_p_s_at(time::TaiNs tai) const;
  /// The rig's world frame (w0, see MarkTruth::p_w0) from the true world frame at `tai`.
  geometry::Transform T_w0_w_at(time::TaiNs tai) const;
  geometry::Vec3 mark_position_w(int mark_id, time::TaiNs tai) const;
  /// All mark ids of the scene, ascending.
  const std::vector<int>& mark_ids() const { return mark_ids_; }
  const SeparationTrajectory& separation() const { return separation_; }
  const PendulumTrajectory& pendulum() const { return pendulum_; }

  ExposureTruth truth(int k) const;

  /// Fast mode: projected truth + centroid noise with the stated per-mark sigma (Cramer-Rao
  /// bound of the rendered spot x optics.centroid_sigma_factor). Noise is a deterministic
  /// function of (seed, k, camera_index). true_mark_ids (if given) receives the mark id of
  /// each observation (-1 for merged blobs). Exposure and mark fields as a unit reports them.
  void observe(int k, int camera_index, msg::MarkObservations& out,
               std::vector<int>* true_mark_ids = nullptr) const;

  /// Full frame (8-bit, width*height bytes, stride = width), shot/read noise etc.
  void render(int k, int camera_index, std::vector<std::uint8_t>& image) const;
  /// The same into a caller buffer (no allocation once the renderer is warm).
  void render_into(int k, int camera_index, std::uint8_t* image, int stride,
                   SpotRenderer& renderer) const;
  /// A background frame of this camera (every pixel from the no-spot distribution), the
  /// pool_index-th of its own random stream: a source that cannot render whole frames at the
  /// frame rate keeps a pool of these and draws only each exposure's spots over one.
  void render_background_into(int pool_index, int camera_index, std::uint8_t* image, int stride,
                              SpotRenderer& renderer) const;
  /// The spots of exposure k (their boxes' pixels, shot + read noise) drawn over the background
  /// already in `image`; renderer.drawn_boxes() then names the pixels written.
  /// With `unit_normals`: the Gaussian approximation (SpotRenderer::render_spots_gaussian) read
  /// from a random offset of that table.
  void render_spots_into(int k, int camera_index, std::uint8_t* image, int stride,
                         SpotRenderer& renderer, std::span<const float> unit_normals = {}) const;
  /// Spots of every visible mark (the scene as the renderer sees it).
  void spots(int k, int camera_index, std::vector<Spot>& out,
             std::vector<int>* mark_ids = nullptr) const;

 private:
  struct Body {
    const survey::RigidBodySurvey* survey = nullptr;  // true coordinates
    int kind = 0;                                     // 0 pylon, 1 store, 2 pendulum, 3 scale bar
    geometry::Transform T_p_b = geometry::Transform::Identity();  // static bodies
  };
  struct MarkRef {
    int id;
    std::size_t body;
    geometry::Vec3 p_body;
  };
  struct CameraTiming {
    time::TaiNs true_start, reported_start;
  };
  geometry::Transform T_p_body(const Body& body, double t) const;
  geometry::Vec3 position_w(const MarkRef& m, double t) const;
  geometry::Transform T_w_c_at(int camera_index, double t) const;
  CameraTiming timing(int k, int camera_index) const;
  MarkCameraTruth see(const MarkRef& m, int camera_index, double t_start, double t_end) const;
  void draw_shared_registration_error();
  void observe_with_noise(int k, int camera_index, std::uint64_t noise_purpose,
                          msg::MarkObservations& out, std::vector<int>* true_mark_ids) const;
  std::uint64_t stream_seed(std::uint64_t purpose, std::uint64_t a, std::uint64_t b) const;

  Scenario sc_;
  std::uint64_t seed_;
  std::vector<geometry::Transform> T_p_c_;
  std::vector<double> vibration_phase_;
  std::vector<double> unit_ptp_offset_ns_;
  camera::RigCalibration true_rig_, calibrated_rig_;
  survey::RigidBodySurvey pylon_surveyed_, store_surveyed_, pendulum_surveyed_;
  std::vector<survey::RigidBodySurvey> bars_true_, bars_surveyed_;
  std::vector<Body> bodies_;
  std::vector<MarkRef> marks_;
  std::vector<int> mark_ids_;
  SeparationTrajectory separation_;
  PendulumTrajectory pendulum_;
};

/// Ground truth as two CSV files (header row names every column with its unit):
///  poses_path: one row per exposure: trigger_seq, trigger/reference TAI ns, T_w_p and T_p_s
///    (translation m, yaw/pitch/roll rad, rotation vector rad), per camera true and reported
///    exposure start TAI ns;
///  marks_path: one row per exposure and mark: trigger_seq, reference TAI, mark_id, p_w (m),
///    v_w (m/s), p_w0 (m, the rig's world frame, see MarkTruth), and per camera visible (0/1),
///    u, v, blur (px).
void write_truth_csv(const Simulator& sim, const std::string& poses_path,
                     const std::string& marks_path);

}  // namespace storetrack::sim
