// Noise-floor characterisation of a static record (Ngeljaratan & Moustafa, seed 002 of
// ../shared/docs/method.md; docs/evaluation.md "Noise floor"): the marks do not move, so every
// change of their measured position is the instrument's noise floor.
//  - variance error: temporal (standard deviation of each mark over time, averaged over marks)
//    and spatial (standard deviation over the marks at each exposure of the displacement from
//    the mark's surveyed position, averaged over time), per world axis and per rig axis
//    (in-plane 1, in-plane 2, out-of-plane: the cameras' mean viewing direction);
//  - bias error per axis: each mark's mean position minus its surveyed position;
//  - image-coordinate error per camera (reprojection residuals and the centroid's scatter over
//    time against its stated sigma), stereo angle per camera pair at each mark;
//  - reconstruction error of the surveyed distances between marks, in %.
// The temporal standard deviation is compared with the host's stated centroid-only per-sample
// u (the calibration part of the stated u does not change over a static record).
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/eval/marks_csv.hpp"
#include "storetrack/survey/survey.hpp"

namespace storetrack::eval {

struct NoiseFloorOptions {
  bool pylon = true, store = false;  ///< marks of these bodies are evaluated
  std::string bodies() const { return std::string(pylon ? "p" : "") + (store ? "s" : ""); }
  double coverage_factor = 2;     ///< k of the expanded uncertainty U = k u
  double agreement_level = 0.95;  ///< two-sided level of the chi-square intervals
  int min_samples = 10;           ///< exposures a record (and a mark) needs
};

/// The rig's directions in the world frame (unit vectors): out-of-plane is the mean of the
/// cameras' optical axes; in-plane 1 the principal direction of the camera centres across it
/// (the baseline); in-plane 2 completes a right-handed frame.
struct RigAxes {
  std::array<geometry::Vec3, 3> axis;  ///< in-plane 1, in-plane 2, out-of-plane
};
RigAxes rig_axes(const camera::RigCalibration& rig);

/// One mark on one axis.
struct AxisNoise {
  double temporal_sd_m = 0;  ///< experimental standard deviation over the record
  double bias_m = 0;         ///< mean position minus surveyed position
  double u_bias_m = 0;       ///< sqrt(s^2 / n + sigma_survey^2) (white noise assumed)
  bool bias_within_k_u = false;
  double u_stated_m = 0;    ///< RMS of the host's stated total per-sample u (CSV)
  double u_centroid_m = 0;  ///< RMS of the stated centroid-only u (needs rig + observations)
  double ratio = 0;         ///< temporal_sd / u_centroid (0 when u_centroid is unknown)
  bool agrees = false;      ///< ratio inside [ratio_low, ratio_high]
};

struct MarkNoise {
  int mark_id = 0;
  char body = '?';
  int samples = 0;
  double ratio_low = 0, ratio_high = 0;  ///< sqrt(chi2_{(1-+level)/2}(n-1) / (n-1))
  geometry::Vec3 mean_p_w = geometry::Vec3::Zero();
  std::array<AxisNoise, 3> world;  ///< x, y, z of the world frame
  std::array<AxisNoise, 3> rig;    ///< in-plane 1, in-plane 2, out-of-plane (needs the rig)
};

/// Seed 002's per-axis numbers over the evaluated marks.
struct AxisNoiseSummary {
  double temporal_sd_mean_m = 0;  ///< mean over marks of the temporal sd (seed 002: mu_T)
  double temporal_sd_rms_m = 0;
  double spatial_sd_mean_m = 0;  ///< mean over exposures of the sd over marks (mu_S)
  double bias_mean_m = 0;        ///< mean over marks of the bias (seed 002's bias error)
  double bias_rms_m = 0, bias_max_abs_m = 0;
  double u_stated_rms_m = 0, u_centroid_rms_m = 0;
  double pooled_ratio = 0;                 ///< sqrt(sum (n-1) s^2/u_c^2 / sum (n-1))
  double pooled_low = 0, pooled_high = 0;  ///< its chi-square interval
  std::int64_t pooled_dof = 0;             ///< sum over marks of (n - 1)
  int agreeing_marks = 0, bias_within_k_u = 0;
};

/// One camera's image coordinates (u column, v row) [px].
struct ImageAxisNoise {
  double residual_rms_px = 0;      ///< reprojection residual against the triangulated point
  double temporal_sd_mean_px = 0;  ///< mean over marks of the centroid's sd over time
  double sigma_rms_px = 0;         ///< RMS of the stated centroid sigma
  double pooled_ratio = 0;         ///< sqrt(sum (n-1) s^2/sigma^2 / sum (n-1))
  double pooled_low = 0, pooled_high = 0;
  bool agrees = false;
};

struct CameraImageNoise {
  int camera_id = 0;
  int marks = 0;
  std::int64_t observations = 0, without_pixel = 0;
  std::int64_t pooled_dof = 0;         ///< sum over marks of (n - 1)
  std::array<ImageAxisNoise, 2> axis;  ///< u, v
};

/// Seed 002 eq. (3) at one mark for one camera pair: theta_c is the angle between the line of
/// sight from the mark to camera c and the rig's reversed out-of-plane direction (the
/// orientation of the target towards the camera); stereo angle between the two lines of sight.
struct StereoAngle {
  int mark_id = 0, camera_a = 0, camera_b = 0;
  double stereo_angle_rad = 0;
  double theta_a_rad = 0, theta_b_rad = 0;
  double error_rad = 0;  ///< e_theta = theta_a - theta_b
};

/// Seed 002 eq. (4): a surveyed distance measured from the marks' mean positions.
struct DistanceError {
  int id_a = 0, id_b = 0;
  int samples = 0;           ///< exposures that saw both
  double reference_m = 0;    ///< surveyed distance D
  double measured_m = 0;     ///< |mean p_a - mean p_b|
  double temporal_sd_m = 0;  ///< sd over the record of the per-exposure distance
  double u_measured_m = 0;   ///< sqrt(s^2 / n + the survey's sigma of D^2)
  double error_percent = 0;  ///< (measured - D) / D * 100
  double u_error_percent = 0;
};

struct NoiseFloorResult {
  NoiseFloorOptions options;
  std::int64_t exposures = 0;  ///< distinct trigger_seq with an evaluated mark
  double duration_s = 0;       ///< first to last reference_mid_tai_ns (0 without the column)
  bool has_rig = false, has_observations = false;
  std::string image_coordinates_note;  ///< why the image-coordinate part is left out (or "")
  RigAxes axes;
  std::vector<MarkNoise> marks;  ///< ascending id
  std::array<AxisNoiseSummary, 3> world_summary, rig_summary;
  std::vector<CameraImageNoise> cameras;
  std::vector<StereoAngle> stereo_angles;
  std::vector<DistanceError> distances;
  double max_retriangulation_m = 0;             ///< largest |offline triangulation - CSV position|
  std::vector<int> marks_with_too_few_samples;  ///< counted, not evaluated
  std::vector<int> surveyed_marks_not_seen;
  std::int64_t other_body_samples = 0, excluded_rows = 0;
};

/// Throws EvalInputError: a survey not in the world frame, a mark of the evaluated bodies absent
/// from the survey, fewer than min_samples exposures, fewer than 2 evaluated marks, a camera of
/// the record absent from the rig.
NoiseFloorResult evaluate_noise_floor(const MarksRecording& record,
                                      const survey::RigidBodySurvey& reference,
                                      const std::string& survey_path,
                                      const camera::RigCalibration* rig,
                                      const std::string& rig_path,
                                      const NoiseFloorOptions& options = {});

}  // namespace storetrack::eval
