// Two calibrations of one rig compared, and the predicted uncertainty of a triangulated mark
// over the working volume (docs/calibration.md, "Compare" and "Uncertainty map").
//
// Projection difference: mrcal's idea (mrcal-show-projection-diff, mrcal.projection_diff and
// its implied transformation, http://mrcal.secretsauce.net/differencing.html), for a whole rig:
// every camera's pixel grid is unprojected with calibration a at the working distances, the
// points are mapped from a's world frame to b's by ONE rigid motion fitted over all cameras
// (so a common shift of the whole rig, e.g. another world registration, does not count), and
// projected with b. Triangulated difference: the same pixels triangulated with a and with b
// (estimation/triangulate), against both predicted calibration covariances.
#pragma once

#include <array>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/survey/scale_bars.hpp"

namespace storetrack::calib {

/// Axis-aligned box in the world frame [m].
struct WorkingVolume {
  geometry::Vec3 min_w = geometry::Vec3::Zero(), max_w = geometry::Vec3::Zero();
};

/// Working distances when none are given: 0.5, 1 and 1.5 times the median distance from the
/// cameras to the least-squares intersection of their optical axes. Throws CalibrationError
/// (naming `origin`) when the axes are (nearly) parallel.
std::vector<double> default_working_distances(const camera::RigCalibration& rig,
                                              const std::string& origin);

/// The box around the points (each camera's pixel grid unprojected at `distances`) that at
/// least 2 cameras see. Throws CalibrationError (naming `origin`) when there are none.
WorkingVolume default_working_volume(const camera::RigCalibration& rig,
                                     const std::vector<double>& distances,
                                     const std::string& origin);

/// Grid of n[0] x n[1] x n[2] points spanning the box (x fastest).
std::vector<geometry::Vec3> volume_grid(const WorkingVolume& v, const std::array<int, 3>& n);

struct CompareOptions {
  std::string origin_a = "a", origin_b = "b";  ///< file names in messages
  std::vector<double> distances_m;             ///< empty: default_working_distances(a)
  std::optional<WorkingVolume> volume;         ///< none: default_working_volume(a)
  std::array<int, 3> volume_points = {11, 11, 11};
  int grid_columns = 32, grid_rows = 18;  ///< projection grid per camera
  double sigma_px = 0.05;                 ///< centroid sigma (the scale-bar triangulation)
  /// A cell of a file's observed_region counts as observed with at least this many points: a
  /// cell with a few is mostly the edge of a board, i.e. extrapolation (docs/calibration.md).
  int min_points_per_cell = 10;
  /// A grid point is inconsistent when d^T (S_a + S_b)^-1 d exceeds the chi-square(3) quantile
  /// at 1 - point_false_alarm (the map; the points are correlated, so the fraction of failing
  /// points is no test: the verdict uses the joint test).
  double point_false_alarm = 0.01;
  /// The sets are declared inconsistent (do not fly) when the joint test over the volume has
  /// p below this (a consistent pair is refused with this probability).
  double false_alarm = 0.01;
};

/// Percentiles of a sample (empty: zeros).
struct Statistics {
  int count = 0;
  double rms = 0, max = 0, p50 = 0, p95 = 0, p99 = 0;
};
Statistics statistics_of(std::vector<double> values);

struct CameraProjectionDifference {
  int camera_id = 0;
  int columns = 0, rows = 0;
  std::vector<geometry::Vec2> pixels;  ///< grid pixels (column fastest)
  /// Per grid pixel: inside the observed region of both calibrations (or of every calibration
  /// that records one). Only these pixels enter the fit and `fitted` / `unfitted`.
  std::vector<bool> inside;
  int outside_pixels = 0;  ///< grid pixels outside (their differences are extrapolation)
  /// Per distance (outer) and grid pixel (inner): |project_b(T p_a) - pixel| [px] with the
  /// fitted rigid motion (NaN where a or b cannot unproject / project).
  std::vector<std::vector<double>> difference_px;
  std::vector<std::vector<double>> difference_unfitted_px;  ///< the same without the fit
  Statistics fitted, unfitted;  ///< over all distances and the pixels inside
  Statistics fitted_outside;    ///< the pixels outside: models evaluated beyond their data
};

struct VolumePointDifference {
  geometry::Vec3 p_w = geometry::Vec3::Zero();  ///< grid point (world of a)
  int cameras = 0;                              ///< cameras of a that see it
  /// Of those, the cameras whose pixel is inside the observed regions; the triangulation
  /// uses only these.
  int cameras_inside = 0;
  bool outside = false;  ///< seen by >= 2 cameras but by fewer than 2 inside: left out
  bool valid = false;    ///< triangulated with both (>= 2 cameras inside)
  geometry::Vec3 difference_m = geometry::Vec3::Zero();  ///< p_b - p_a, same pixels
  geometry::Mat3 cov_a = geometry::Mat3::Zero();         ///< a's calibration part [m^2]
  geometry::Mat3 cov_b = geometry::Mat3::Zero();
  double chi2 = 0;  ///< d^T (S_a + S_b)^-1 d
  bool inconsistent = false;
};

struct BarComparison {
  std::string id;
  double length_m = 0, u_length_m = 0;
  bool valid = false;    ///< both marks triangulated with both calibrations
  double error_a_m = 0;  ///< |p_A - p_B| - length with a
  double error_b_m = 0;
  double u_a_m = 0, u_b_m = 0;  ///< predicted standard uncertainty of the error (all sources)
  std::string reason;           ///< why not valid
};

struct ComparisonResult {
  std::vector<double> distances_m;
  WorkingVolume volume;
  geometry::Transform T_b_a = geometry::Transform::Identity();  ///< fitted: world a -> world b
  std::vector<CameraProjectionDifference> cameras;
  std::vector<VolumePointDifference> points;
  Statistics difference_m;                  ///< |p_b - p_a| over valid points
  Statistics u_a_m, u_b_m;                  ///< sqrt(trace S) over valid points
  double chi2_threshold = 0;                ///< chi-square(3) quantile used
  double inconsistent_fraction = 0;         ///< of the valid points
  int valid_points = 0, unseen_points = 0;  ///< unseen: fewer than 2 cameras
  int outside_points = 0;  ///< seen by >= 2 cameras, but inside the observed regions by < 2
  /// One line each: a calibration without an observed-region record (the comparison cannot
  /// check it), a model evaluated beyond its data (grid pixels, volume points left out).
  std::vector<std::string> warnings;
  /// All valid points jointly (their differences share the calibration errors): the
  /// chi-square of the stacked differences against their joint covariance, its degrees of
  /// freedom (rank) and p-value. The verdict's consistency test.
  double joint_chi2 = 0;
  int joint_dof = 0;
  double joint_p_value = 1;
  std::vector<BarComparison> bars;
  bool consistent = true;
  char better = '=';    ///< 'a', 'b' or '=' (equal within 5 %)
  std::string verdict;  ///< one paragraph: which set and why, or "do not fly"
};

/// Scale-bar marks seen in the images: (camera id, mark id, pixel).
struct BarSighting {
  int camera = 0;
  int mark_id = 0;
  geometry::Vec2 pixel_px = geometry::Vec2::Zero();
};

/// Throws CalibrationError naming the file and field when a and b are not the same rig
/// (camera count, camera ids, image sizes).
void check_same_rig(const camera::RigCalibration& a, const camera::RigCalibration& b,
                    const std::string& origin_a, const std::string& origin_b);

ComparisonResult compare_calibrations(const camera::RigCalibration& a,
                                      const camera::RigCalibration& b,
                                      const CompareOptions& options,
                                      const survey::ScaleBarSet* bars = nullptr,
                                      const std::vector<BarSighting>& bar_sightings = {});

/// Compare's projection difference for one camera alone (cross-validation, model_error_check.hpp):
/// per pixel, project_b(T_b_a unproject_a(pixel) at distance_m) - pixel [px], with T_b_a the rigid
/// motion fitted over the pixels unprojected at every fit distance (NaN where a model cannot
/// unproject or project).
std::vector<geometry::Vec2> projection_difference(const camera::CameraModel& a,
                                                  const camera::CameraModel& b,
                                                  const std::vector<geometry::Vec2>& pixels,
                                                  const std::vector<double>& fit_distances_m,
                                                  double distance_m);

/// The predicted uncertainty over the working volume.
struct UncertaintyMapOptions {
  std::string origin = "rig";
  std::vector<double> distances_m;  ///< for the default volume
  std::optional<WorkingVolume> volume;
  std::array<int, 3> volume_points = {21, 21, 21};
  double sigma_px = 0.05;
};

struct UncertaintyMapPoint {
  geometry::Vec3 p_w = geometry::Vec3::Zero();
  int cameras = 0;
  bool valid = false;  ///< >= 2 cameras and triangulated
  geometry::Mat3 cov_centroid = geometry::Mat3::Zero(), cov_calibration = geometry::Mat3::Zero();
};

struct UncertaintyMap {
  WorkingVolume volume;
  std::array<int, 3> n{};
  std::vector<UncertaintyMapPoint> points;  ///< x fastest
  std::string covariance_source;
};

UncertaintyMap uncertainty_map(const camera::RigCalibration& rig,
                               const UncertaintyMapOptions& options);

}  // namespace storetrack::calib
