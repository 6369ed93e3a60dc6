// Cross-validation and residual map per camera (docs/calibration.md, "Model error").
#include "storetrack/calib/model_error_check.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>
#include <utility>

#include <Eigen/Eigenvalues>

#include "storetrack/calib/calibration_comparison.hpp"
#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::calib {
namespace {

using geometry::Mat2;
using geometry::Vec2;

ModelErrorTest empty_test(const ModelErrorOptions& o, int width, int height) {
  ModelErrorTest t;
  t.columns = o.columns;
  t.rows = o.rows;
  for (int r = 0; r < o.rows; ++r)
    for (int c = 0; c < o.columns; ++c) {
      ModelErrorCell cell;
      cell.column = c;
      cell.row = r;
      cell.centre_px = Vec2((c + 0.5) * width / o.columns - 0.5, (r + 0.5) * height / o.rows - 0.5);
      t.cells.push_back(cell);
    }
  t.cell_threshold = uncertainty::chi_square_quantile(
      uncertainty::Probability(1 - o.cell_false_alarm), uncertainty::DegreesOfFreedom(2));
  return t;
}

/// Flags the tested cells above the threshold and decides against the binomial band.
void decide(ModelErrorTest& t, const ModelErrorOptions& o) {
  t.tested_cells = t.flagged_cells = 0;
  for (ModelErrorCell& c : t.cells) {
    if (!c.tested) continue;
    ++t.tested_cells;
    c.flagged = c.chi2 > t.cell_threshold;
    t.flagged_cells += c.flagged ? 1 : 0;
  }
  t.allowed_cells =
      t.tested_cells == 0
          ? 0
          : static_cast<int>(uncertainty::binomial_interval(t.tested_cells, o.cell_false_alarm,
                                                            o.camera_false_alarm)
                                 .high);
  t.model_error = t.flagged_cells > t.allowed_cells;
  t.available = t.tested_cells > 0;
  if (!t.available && t.reason.empty()) t.reason = "no cell with enough points";
}

double chi2_of(const Vec2& d, const Mat2& C) {
  Mat2 C_inv;
  if (uncertainty::inverse_spd<2>(C, C_inv)) return d.dot(C_inv * d);
  return d.norm() == 0 ? 0.0 : std::numeric_limits<double>::infinity();
}

/// The set restricted to `camera` and `frames`.
ObservationSet subset(const ObservationSet& set, int camera, const std::vector<int>& frames) {
  ObservationSet out;
  out.image_sizes = set.image_sizes;
  for (const Observation& ob : set.observations)
    if (ob.camera == camera && std::binary_search(frames.begin(), frames.end(), ob.frame))
      out.observations.push_back(ob);
  return out;
}

struct Half {
  camera::Intrinsics intrinsics;
  camera::IntrinsicCovariance covariance;
};

/// The stacked projection differences b - a at `pixels` (2 per pixel).
Eigen::VectorXd stacked_difference(const camera::IntrinsicVector& a,
                                   const camera::IntrinsicVector& b, int width, int height,
                                   camera::LensModel lens_model, const std::vector<Vec2>& pixels,
                                   const std::vector<double>& fit_distances, double distance) {
  const auto d =
      projection_difference(camera::CameraModel(camera::unpack(a, width, height, lens_model)),
                            camera::CameraModel(camera::unpack(b, width, height, lens_model)),
                            pixels, fit_distances, distance);
  Eigen::VectorXd out(2 * static_cast<Eigen::Index>(d.size()));
  for (size_t i = 0; i < d.size(); ++i)
    out.segment<2>(2 * static_cast<Eigen::Index>(i)) = d[i];
  return out;
}

/// Covariance of the stacked difference: J_a S_a J_a^T + J_b S_b J_b^T (independent halves), the
/// Jacobians by central differences through the fit (steps of 0.1 sigma of each free parameter).
Eigen::MatrixXd difference_covariance(const Half& a, const Half& b, const std::vector<Vec2>& pixels,
                                      const std::vector<double>& fit_distances, double distance) {
  const int w = a.intrinsics.width, h = a.intrinsics.height;
  const camera::LensModel lens = a.intrinsics.lens_model;
  const camera::IntrinsicVector pa = camera::pack(a.intrinsics), pb = camera::pack(b.intrinsics);
  const auto n = 2 * static_cast<Eigen::Index>(pixels.size());
  Eigen::MatrixXd C = Eigen::MatrixXd::Zero(n, n);
  for (int side = 0; side < 2; ++side) {
    const camera::IntrinsicCovariance& S = side == 0 ? a.covariance : b.covariance;
    Eigen::MatrixXd J = Eigen::MatrixXd::Zero(n, camera::kNumIntrinsics);
    for (int k = 0; k < camera::kNumIntrinsics; ++k) {
      if (!(S(k, k) > 0)) continue;  // fixed parameter
      camera::IntrinsicVector step = camera::IntrinsicVector::Zero();
      step(k) = 0.1 * std::sqrt(S(k, k));
      const auto f = [&](double sign) {
        return side == 0 ? stacked_difference(pa + sign * step, pb, w, h, lens, pixels,
                                              fit_distances, distance)
                         : stacked_difference(pa, pb + sign * step, w, h, lens, pixels,
                                              fit_distances, distance);
      };
      J.col(k) = (f(1) - f(-1)) / (2 * step(k));
    }
    C += J * S * J.transpose();
  }
  return C;
}

/// Calibrates the frames of one half; throws CalibrationError.
Half calibrate_half(const ObservationSet& set, int camera, const std::vector<int>& frames,
                    const IntrinsicOptions& options, std::vector<double>& depths) {
  const IntrinsicResult r = calibrate_intrinsics(subset(set, camera, frames), camera, options);
  for (const ViewResult& v : r.views)
    depths.push_back(v.T_c_b.translation().z());
  return {r.intrinsics, r.covariance};
}

/// Directions of the joint test weaker than this fraction of the strongest are left out (the
/// first-order model does not hold there; compare's kJointRelativeSingularValue, in variance).
constexpr double kJointRelativeEigenvalue = 1e-6;

/// The joint chi-square of the stacked differences d against C (pseudo-inverse) and the verdict.
void joint_decision(const Eigen::VectorXd& d, const Eigen::MatrixXd& C, ModelErrorTest& t,
                    const ModelErrorOptions& o) {
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(C);
  const Eigen::VectorXd& l = eig.eigenvalues();
  const Eigen::VectorXd projected = eig.eigenvectors().transpose() * d;
  t.joint_chi2 = 0;
  t.joint_dof = 0;
  for (Eigen::Index i = 0; i < l.size(); ++i) {
    if (!(l(i) > kJointRelativeEigenvalue * l.maxCoeff()) || !std::isfinite(projected(i))) continue;
    t.joint_chi2 += projected(i) * projected(i) / l(i);
    ++t.joint_dof;
  }
  t.joint_p_value = t.joint_dof > 0 ? uncertainty::chi_square_survival(
                                          t.joint_chi2, uncertainty::DegreesOfFreedom(t.joint_dof))
                                    : 1.0;
  t.model_error = t.joint_p_value < o.camera_false_alarm;
}

std::string cell_list(const ModelErrorTest& t) {
  std::ostringstream s;
  s.precision(4);
  bool first = true;
  for (const ModelErrorCell& c : t.cells) {
    if (!c.flagged) continue;
    s << (first ? "" : ", ") << "(" << c.column << "," << c.row << ") at (" << c.centre_px.x()
      << ", " << c.centre_px.y() << ") px";
    first = false;
  }
  return s.str();
}

std::string test_summary(const std::string& name, const ModelErrorTest& t) {
  if (!t.available) return name + " not run (" + t.reason + ")";
  std::ostringstream joint;
  joint.precision(3);
  if (t.joint_dof > 0)
    joint << ", joint chi2 " << t.joint_chi2 << " for " << t.joint_dof << " dof, p "
          << t.joint_p_value;
  return name + " " + std::to_string(t.flagged_cells) + " of " + std::to_string(t.tested_cells) +
         " cells flagged" +
         (t.joint_dof > 0 ? joint.str()
                          : " (noise allows " + std::to_string(t.allowed_cells) + ")") +
         (t.model_error ? ": " + cell_list(t) : "");
}

}  // namespace

ModelErrorTest residual_map_test(const ObservationSet& set, int camera,
                                 const std::vector<PointResidual>& residuals, int width, int height,
                                 double residual_sigma, const ModelErrorOptions& o) {
  ModelErrorTest t = empty_test(o, width, height);
  std::map<std::pair<int, int>, const Observation*> by_point;  // (frame, point) -> observation
  for (const Observation& ob : set.observations)
    if (ob.camera == camera) by_point[{ob.frame, ob.point_id}] = &ob;
  const camera::ObservedRegion grid{o.columns, o.rows, {}};
  std::vector<Vec2> z_sum(t.cells.size(), Vec2::Zero()), r_sum(t.cells.size(), Vec2::Zero());
  std::vector<double> r2_sum(t.cells.size(), 0), w2_sum(t.cells.size(), 0);
  for (const PointResidual& p : residuals) {
    const auto it = by_point.find({p.frame, p.point_id});
    if (p.rejected || it == by_point.end()) continue;
    const int cell = grid.cell_of(it->second->pixel, width, height);
    if (cell < 0) continue;
    const auto i = static_cast<size_t>(cell);
    const double sigma = it->second->weighting_sigma_px() * residual_sigma;
    z_sum[i] += p.residual_px / sigma;
    r_sum[i] += p.residual_px;
    r2_sum[i] += p.residual_px.squaredNorm();
    w2_sum[i] += sigma * sigma;
    ++t.cells[i].points;
  }
  for (size_t i = 0; i < t.cells.size(); ++i) {
    ModelErrorCell& c = t.cells[i];
    if (c.points == 0) continue;
    const double n = c.points;
    c.value_px = r_sum[i] / n;
    c.rms_px = std::sqrt(r2_sum[i] / (2 * n));
    c.sigma_px = std::sqrt(w2_sum[i] / n) / std::sqrt(n);
    c.tested = c.points >= o.min_points_per_cell;
    c.chi2 = z_sum[i].squaredNorm() / n;  // sum of n N(0, I) over sqrt(n): N(0, I)
  }
  decide(t, o);
  return t;
}

ModelErrorTest cross_validation_test(const ObservationSet& set, int camera,
                                     const std::vector<int>& frames,
                                     const IntrinsicOptions& options,
                                     const ModelErrorTest& residual_cells,
                                     const ModelErrorOptions& o, double& distance_m) {
  ModelErrorTest t = residual_cells;
  for (ModelErrorCell& c : t.cells) {
    c.tested = c.flagged = false;
    c.value_px.setZero();
    c.chi2 = c.rms_px = c.sigma_px = 0;
  }
  std::vector<int> sorted = frames, half_a, half_b;
  std::sort(sorted.begin(), sorted.end());
  for (size_t i = 0; i < sorted.size(); ++i)
    (i % 2 == 0 ? half_a : half_b).push_back(sorted[i]);
  std::vector<double> depths;
  Half a, b;
  try {
    a = calibrate_half(set, camera, half_a, options, depths);
    b = calibrate_half(set, camera, half_b, options, depths);
  } catch (const std::exception& e) {  // CalibrationError: too few views, degenerate half
    t.reason = std::string("a half of the views cannot be calibrated alone: ") + e.what();
    decide(t, o);
    return t;
  }
  std::nth_element(depths.begin(), depths.begin() + static_cast<long>(depths.size() / 2),
                   depths.end());
  distance_m = depths[depths.size() / 2];
  const std::vector<double> fit = {0.5 * distance_m, distance_m, 1.5 * distance_m};
  std::vector<Vec2> pixels;
  std::vector<size_t> cell_of_pixel;
  for (size_t i = 0; i < t.cells.size(); ++i)
    if (t.cells[i].points >= o.min_points_per_cell) {
      pixels.push_back(t.cells[i].centre_px);
      cell_of_pixel.push_back(i);
    }
  const Eigen::VectorXd d =
      stacked_difference(camera::pack(a.intrinsics), camera::pack(b.intrinsics), a.intrinsics.width,
                         a.intrinsics.height, a.intrinsics.lens_model, pixels, fit, distance_m);
  const Eigen::MatrixXd C = difference_covariance(a, b, pixels, fit, distance_m);
  for (size_t k = 0; k < pixels.size(); ++k) {
    const auto j = 2 * static_cast<Eigen::Index>(k);
    ModelErrorCell& c = t.cells[cell_of_pixel[k]];
    c.value_px = d.segment<2>(j);
    const Mat2 Ck = C.block<2, 2>(j, j);
    c.sigma_px = std::sqrt(0.5 * Ck.trace());
    c.chi2 = chi2_of(c.value_px, Ck);
    c.tested = std::isfinite(c.chi2);
  }
  decide(t, o);
  if (d.allFinite()) joint_decision(d, C, t, o);
  return t;
}

ModelErrorCheck check_model_error(const ObservationSet& set, int camera,
                                  const std::vector<int>& frames,
                                  const std::vector<PointResidual>& residuals, int width,
                                  int height, double residual_sigma,
                                  const IntrinsicOptions& options, const ModelErrorOptions& o) {
  ModelErrorCheck check;
  check.camera_id = camera;
  check.residual_map = residual_map_test(set, camera, residuals, width, height, residual_sigma, o);
  check.cross_validation = cross_validation_test(set, camera, frames, options, check.residual_map,
                                                 o, check.cross_validation_distance_m);
  check.model_error = check.residual_map.model_error || check.cross_validation.model_error;
  const bool checked = check.residual_map.available || check.cross_validation.available;
  check.verdict = std::string(check.model_error ? "model error dominates here: "
                              : checked         ? "noise dominates: "
                                                : "model error not checked: ") +
                  test_summary("cross-validation", check.cross_validation) + "; " +
                  test_summary("residual map", check.residual_map);
  return check;
}

}  // namespace storetrack::calib
