// World registration: S_r (reference camera, camera 0) -> S_w (aircraft) from marks surveyed by
// a total station in S_w and seen by the rig's cameras (docs/calibration.md, "Register").
//
// Each mark is triangulated in S_r (estimation/triangulate) through the rig calibration, with its
// covariance from the centroid sigma and from the calibration's (joint) covariance; T_r_w is
// fitted by estimation/pose (weighted absolute orientation, then Gauss-Newton with each mark
// weighted by its triangulation covariance plus its survey covariance). The covariance of T_r_w is
// propagated from all three sources, keeping the correlation between marks that share the
// calibration. Every camera's T_c_w = T_c_r T_r_w with the joint covariance of the result.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/survey/survey.hpp"

namespace storetrack::calib {

/// One camera's image of one surveyed mark (a row of the marks observation CSV).
struct MarkSighting {
  int camera = 0;
  int mark_id = 0;  ///< the survey's mark id (the CSV's point_id)
  geometry::Vec2 pixel_px = geometry::Vec2::Zero();
  double sigma_px = 0;  ///< per-axis centroid standard uncertainty [px], > 0
};

struct RegistrationOptions {
  /// Names used in error messages and the report (file names in the program).
  std::string rig_origin = "rig calibration";
  std::string survey_origin = "survey";
  std::string observations_origin = "observations";
  /// Per-mark test: a mark is named an outlier when its statistic exceeds the chi-square
  /// quantile at 1 - outlier_false_alarm / (usable marks) (a clean set names any mark with this
  /// probability).
  double outlier_false_alarm = 0.01;
  /// Reject the worst failing mark and refit while one fails and more than 3 remain (a rejected
  /// mark is still tested, against the fit without it); false: only name them.
  bool reject_outliers = true;
  /// Marks are refused as collinear when the second principal standard deviation of the
  /// surveyed positions is below this fraction of the first.
  double collinearity_ratio = 1e-3;
};

/// Layout of the joint calibration covariance (input and output): per camera (in the rig's
/// order) the 13 packed intrinsics, then the left perturbation (rx, ry, rz, tx, ty, tz) of its
/// extrinsic (T_c_r in the input, T_c_w in the output). Same as calib::kRigBlockSize.
inline constexpr int kRegistrationBlockSize = camera::kJointBlockSize;

struct MarkRegistration {
  int mark_id = 0;
  std::vector<int> cameras;                            ///< cameras that saw it
  geometry::Vec3 p_r = geometry::Vec3::Zero();         ///< triangulated in S_r [m]
  geometry::Mat3 cov_r = geometry::Mat3::Zero();       ///< its covariance: centroid + calibration
  geometry::Vec3 q_w = geometry::Vec3::Zero();         ///< surveyed in S_w [m]
  double survey_sigma_m = 0;                           ///< per axis
  double reprojection_chi2 = 0;                        ///< the triangulation's
  geometry::Vec3 residual_r = geometry::Vec3::Zero();  ///< p_r - T_r_w q_w [m]
  double chi2 = 0;     ///< r^T C_r^+ r, C_r the residual's covariance (all sources)
  int dof = 0;         ///< rank of C_r (3 with >= 4 marks)
  double p_value = 1;  ///< P(chi2(dof) > chi2)
  bool used = true;    ///< in the fit (false: rejected as an outlier)
  /// Failed the test (p < outlier_false_alarm / used marks): rejected, or kept when rejection
  /// is off or only 3 marks remain.
  bool outlier = false;
};

struct SkippedMark {
  int mark_id = 0;
  std::string reason;  ///< names the file and what is missing
};

struct RegistrationResult {
  geometry::Transform T_r_w_start = geometry::Transform::Identity();  ///< absolute orientation
  geometry::Transform T_r_w = geometry::Transform::Identity();        ///< S_w -> S_r
  /// Covariance of the left perturbation of T_r_w (in S_r): total and by source.
  geometry::Mat6 cov_T_r_w = geometry::Mat6::Zero();
  geometry::Mat6 cov_T_r_w_centroid = geometry::Mat6::Zero();
  geometry::Mat6 cov_T_r_w_calibration = geometry::Mat6::Zero();
  geometry::Mat6 cov_T_r_w_survey = geometry::Mat6::Zero();
  geometry::Transform T_w_r = geometry::Transform::Identity();  ///< S_r -> S_w (the inverse)
  geometry::Mat6 cov_T_w_r = geometry::Mat6::Zero();            ///< left perturbation, in S_w
  std::vector<MarkRegistration> marks;                          ///< usable marks, ascending id
  std::vector<SkippedMark> skipped;
  double chi2 = 0;  ///< r^T C^+ r over the used marks (all sources, correlations kept)
  int dof = 0;      ///< 3 marks - 6
  double p_value = 1;
  int iterations = 0;
  /// Scale of the triangulated marks against the survey: p_r = (1 + scale_error) T_r_w q_w,
  /// estimated (generalised least squares) from the used marks' residuals, which the rigid fit
  /// leaves it in; 0 +/- scale_error_sigma when rig and survey agree. A wrong board square size
  /// in the rig step, or a survey in the wrong unit, shows here first.
  double scale_error = 0;
  double scale_error_sigma = 0;
  /// The registered rig: every camera's T_c_w = T_c_r T_r_w, intrinsics unchanged, each
  /// camera's extrinsic block the diagonal block of joint_covariance.
  camera::RigCalibration registered;
  /// Joint covariance of (intrinsics, left perturbation of T_c_w) of all cameras
  /// (kRegistrationBlockSize per camera), cross-camera and intrinsic-extrinsic terms included.
  Eigen::MatrixXd joint_covariance;
};

/// Registers the rig. `rig_r` is the `rig` step's calibration (T_c_w = T_c_r, camera 0 first
/// with T = identity); `calibration_covariance` its joint covariance in the layout above
/// (rig_r.full_joint_covariance() for a file without one). Throws CalibrationError with a
/// message naming the file and field: survey not in frame 'w', a mark id not in the survey, a
/// camera not in the rig, a (camera, mark) seen twice, fewer than 3 usable marks, collinear
/// marks. Marks that cannot be used (seen by fewer than 2 cameras, triangulation failed) are
/// listed in `skipped` with the reason.
RegistrationResult register_rig(const camera::RigCalibration& rig_r,
                                const Eigen::MatrixXd& calibration_covariance,
                                const survey::RigidBodySurvey& survey_w,
                                const std::vector<MarkSighting>& sightings,
                                const RegistrationOptions& options = {});

/// One mark of a surveyed body (pylon, store) in a body registration.
struct BodyMarkRegistration {
  int mark_id = 0;
  std::vector<int> cameras;                            ///< cameras that saw it
  geometry::Vec3 p_w = geometry::Vec3::Zero();         ///< triangulated in S_w [m]
  geometry::Mat3 cov_w = geometry::Mat3::Zero();       ///< its covariance: centroid + calibration
  geometry::Vec3 q_b = geometry::Vec3::Zero();         ///< surveyed in the body frame [m]
  double survey_sigma_m = 0;                           ///< per axis
  double reprojection_chi2 = 0;                        ///< the triangulation's
  geometry::Vec3 residual_w = geometry::Vec3::Zero();  ///< p_w - T_w_b q_b [m]
  double chi2 = 0;                                     ///< as MarkRegistration's
  int dof = 0;
  double p_value = 1;
  bool used = true;
  bool outlier = false;
};

/// A surveyed body (the pylon, frame 'p', or the store, frame 's', on the ground before flight)
/// registered in S_w through the registered rig: its pose, the survey checked against what the
/// cameras see (per-mark chi-square, the fit's chi-square, the scale), docs/calibration.md,
/// "Register the pylon and the store".
struct BodyRegistration {
  std::string body;  ///< the survey's name ("pylon", "store")
  char frame = 'b';  ///< the survey's frame letter
  geometry::Transform T_w_b_start = geometry::Transform::Identity();  ///< absolute orientation
  geometry::Transform T_w_b = geometry::Transform::Identity();        ///< S_b -> S_w
  /// Covariance of the left perturbation of T_w_b (in S_w): total and by source.
  geometry::Mat6 cov_T_w_b = geometry::Mat6::Zero();
  geometry::Mat6 cov_T_w_b_centroid = geometry::Mat6::Zero();
  geometry::Mat6 cov_T_w_b_calibration = geometry::Mat6::Zero();
  geometry::Mat6 cov_T_w_b_survey = geometry::Mat6::Zero();
  /// d(left perturbation of T_w_b)/d(calibration parameters) (6 x kRegistrationBlockSize per
  /// camera): what correlates two bodies registered through the same rig.
  Eigen::Matrix<double, 6, Eigen::Dynamic> d_T_w_b_d_calibration;
  std::vector<BodyMarkRegistration> marks;  ///< usable marks, ascending id
  std::vector<SkippedMark> skipped;
  double chi2 = 0;
  int dof = 0;
  double p_value = 1;
  int iterations = 0;
  double scale_error = 0;  ///< p_w = (1 + scale_error) T_w_b q_b, as RegistrationResult's
  double scale_error_sigma = 0;
};

/// Registers a surveyed body through a registered rig (`rig_w`: T_c_w in S_w, the `register`
/// step's output; `calibration_covariance` its joint covariance, layout above). The same
/// triangulation, weighted fit, tests and propagation as register_rig, with S_w in the place of
/// S_r and the body's frame in the place of S_w. Throws CalibrationError naming the file and
/// field: survey in frame 'w' (that is register_rig's), and every refusal of register_rig.
BodyRegistration register_body(const camera::RigCalibration& rig_w,
                               const Eigen::MatrixXd& calibration_covariance,
                               const survey::RigidBodySurvey& survey_b,
                               const std::vector<MarkSighting>& sightings,
                               const RegistrationOptions& options = {});

/// Body b's pose in body a's frame, T_a_b = T_w_a^-1 T_w_b, from two registrations through the
/// same rig and `calibration_covariance` (e.g. the store's carriage pose on the pylon before
/// flight, T_p_s). The covariance keeps the calibration error the two share; their centroid and
/// survey errors are independent (different marks).
struct RelativePose {
  geometry::Transform T_a_b = geometry::Transform::Identity();
  geometry::Mat6 cov_T_a_b = geometry::Mat6::Zero();  ///< left perturbation, in S_a
};
RelativePose relative_pose(const BodyRegistration& a, const BodyRegistration& b,
                           const Eigen::MatrixXd& calibration_covariance);

}  // namespace storetrack::calib
