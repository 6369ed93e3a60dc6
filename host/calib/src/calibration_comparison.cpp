// compare and uncertainty-map (docs/calibration.md): the projection difference with the rigid
// motion between the two calibrations fitted out, the triangulated difference over the working
// volume against both predicted covariances, scale bars, the verdict; the uncertainty map.
#include "storetrack/calib/calibration_comparison.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <sstream>

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include "storetrack/calib/intrinsic_calibration.hpp"  // CalibrationError
#include "storetrack/calib/point_uncertainty.hpp"
#include "storetrack/pose/body_pose.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::calib {
namespace {

using geometry::Mat3;
using geometry::Transform;
using geometry::Vec2;
using geometry::Vec3;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

Vec3 camera_centre(const camera::CalibratedCamera& c) {
  return -(c.T_c_w.linear().transpose() * c.T_c_w.translation());
}

/// The world point at depth `depth_m` (camera z) on the ray of `pixel`; nullopt when the
/// model cannot undistort it.
std::optional<Vec3> unproject_world(const camera::CalibratedCamera& c, const Vec2& pixel,
                                    double depth_m) {
  const auto xy = c.model.unproject(pixel);
  if (!xy) return std::nullopt;
  const Vec3 p_c(xy->x() * depth_m, xy->y() * depth_m, depth_m);
  return Vec3(c.T_c_w.inverse() * p_c);
}

/// Pixel-centre grid covering the image, column fastest.
std::vector<Vec2> pixel_grid(const camera::Intrinsics& in, int columns, int rows) {
  std::vector<Vec2> out;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < columns; ++c)
      out.emplace_back((c + 0.5) * in.width / columns - 0.5, (r + 0.5) * in.height / rows - 0.5);
  return out;
}

/// True when `pixel` of camera `slot` is in the calibration's observed region, or the file
/// records none (that case is warned about once, by region_warnings).
bool in_observed_region(const camera::RigCalibration& rig, size_t slot, const Vec2& pixel,
                        int min_points) {
  const camera::CalibratedCamera& c = rig.cameras[slot];
  const auto region = rig.observed_regions.find(c.camera_id);
  if (region == rig.observed_regions.end()) return true;
  const auto& in = c.model.intrinsics();
  return region->second.contains(pixel, in.width, in.height, min_points);
}

bool inside_both(const camera::RigCalibration& a, const camera::RigCalibration& b, size_t slot,
                 const Vec2& pixel, int min_points) {
  return in_observed_region(a, slot, pixel, min_points) &&
         in_observed_region(b, slot, pixel, min_points);
}

/// "<file>: camera N has no observed_region record ..." for every camera of a file without one.
void region_warnings(const camera::RigCalibration& rig, const std::string& origin,
                     std::vector<std::string>& warnings) {
  for (const auto& c : rig.cameras)
    if (!rig.observed_regions.contains(c.camera_id))
      warnings.push_back(origin + ": camera " + std::to_string(c.camera_id) +
                         " has no observed_region record: the comparison cannot check that its "
                         "model is evaluated only where it had observations");
}

/// One sample of the projection fit: camera slot, pixel, the point unprojected with a.
struct ProjectionSample {
  int slot = 0;
  Vec2 pixel = Vec2::Zero();
  Vec3 p_wa = Vec3::Zero();
};

/// T_b_a minimising sum |project_b(T_b_a p_wa) - pixel|^2 (Gauss-Newton on its left
/// perturbation), started from the absolute orientation of the points unprojected with both.
Transform fit_rigid_motion(const camera::RigCalibration& b,
                           const std::vector<ProjectionSample>& samples,
                           const std::vector<Vec3>& p_wb_start) {
  std::vector<Vec3> q, p;
  for (size_t i = 0; i < samples.size(); ++i)
    if (p_wb_start[i].allFinite()) {
      q.push_back(samples[i].p_wa);
      p.push_back(p_wb_start[i]);
    }
  const std::vector<double> weights(q.size(), 1.0);
  Transform T = Transform::Identity();
  if (!pose::absolute_orientation(pose::PointsInBody{q}, pose::PointsInWorld{p}, weights, T))
    T = Transform::Identity();
  for (int iteration = 0; iteration < 30; ++iteration) {
    geometry::Mat6 H = geometry::Mat6::Zero();
    geometry::Vec6 g = geometry::Vec6::Zero();
    for (const ProjectionSample& s : samples) {
      const camera::CalibratedCamera& cb = b.cameras[static_cast<size_t>(s.slot)];
      const Vec3 p_wb = T * s.p_wa;
      camera::ProjectionJacobians J;
      const auto u = cb.model.project_world(cb.T_c_w, p_wb, &J);
      if (!u) continue;
      Eigen::Matrix<double, 3, 6> dp;
      dp << -geometry::skew(p_wb - T.translation()), Mat3::Identity();
      const Eigen::Matrix<double, 2, 6> A = J.d_point_world * dp;
      const Vec2 r = *u - s.pixel;
      H += A.transpose() * A;
      g += A.transpose() * r;
    }
    const geometry::Vec6 step = -H.ldlt().solve(g);
    if (!step.allFinite()) break;
    T = geometry::perturb_left(T, step);
    if (step.head<3>().norm() < 1e-13 && step.tail<3>().norm() < 1e-12) break;
  }
  return T;
}

std::vector<ProjectionSample> projection_samples(const camera::RigCalibration& a,
                                                 const camera::RigCalibration& b,
                                                 const CompareOptions& o,
                                                 std::vector<Vec3>& p_wb_start) {
  std::vector<ProjectionSample> out;
  for (size_t s = 0; s < a.cameras.size(); ++s)
    for (double d : o.distances_m)
      for (const Vec2& q :
           pixel_grid(a.cameras[s].model.intrinsics(), o.grid_columns, o.grid_rows)) {
        const auto p_wa = unproject_world(a.cameras[s], q, d);
        if (!p_wa || !inside_both(a, b, s, q, o.min_points_per_cell))
          continue;  // fitted on data-backed pixels only
        out.push_back({static_cast<int>(s), q, *p_wa});
        p_wb_start.push_back(unproject_world(b.cameras[s], q, d).value_or(Vec3::Constant(kNaN)));
      }
  return out;
}

/// project_b(T_b_a unproject_a(q, depth)) - q [px]; NaN where a model cannot (un)project.
Vec2 difference_vector(const camera::CalibratedCamera& ca, const camera::CalibratedCamera& cb,
                       const Vec2& q, double depth_m, const Transform& T_b_a) {
  const auto p_wa = unproject_world(ca, q, depth_m);
  const auto u = p_wa ? cb.model.project_world(cb.T_c_w, T_b_a * *p_wa) : std::nullopt;
  return u ? Vec2(*u - q) : Vec2::Constant(kNaN);
}

/// Pixel difference of every camera's grid through T_b_a (identity: unfitted).
std::vector<std::vector<double>> grid_differences(const camera::RigCalibration& a,
                                                  const camera::RigCalibration& b, int slot,
                                                  const std::vector<Vec2>& grid,
                                                  const std::vector<double>& distances,
                                                  const Transform& T_b_a) {
  const camera::CalibratedCamera &ca = a.cameras[static_cast<size_t>(slot)],
                                 &cb = b.cameras[static_cast<size_t>(slot)];
  std::vector<std::vector<double>> out;
  for (double d : distances) {
    std::vector<double> row;
    for (const Vec2& q : grid)
      row.push_back(difference_vector(ca, cb, q, d, T_b_a).norm());
    out.push_back(std::move(row));
  }
  return out;
}

double chi2_of(const Vec3& d, const Mat3& S) {
  Mat3 S_inv;
  if (uncertainty::inverse_spd<3>(S, S_inv)) return d.dot(S_inv * d);
  return d.norm() == 0 ? 0.0 : std::numeric_limits<double>::infinity();
}

VolumePointDifference compare_point(const camera::RigCalibration& a, const Eigen::MatrixXd& Sa,
                                    const camera::RigCalibration& b, const Eigen::MatrixXd& Sb,
                                    const Vec3& x, const CompareOptions& o, double threshold,
                                    PointUncertainty& pa, PointUncertainty& pb) {
  const double sigma_px = o.sigma_px;
  VolumePointDifference out;
  out.p_w = x;
  std::vector<SlotPixel> pixels = visible_pixels(a, x);
  out.cameras = static_cast<int>(pixels.size());
  std::erase_if(pixels, [&](const SlotPixel& p) {
    return !inside_both(a, b, static_cast<size_t>(p.slot), p.pixel_px, o.min_points_per_cell);
  });
  out.cameras_inside = static_cast<int>(pixels.size());
  out.outside = out.cameras >= 2 && out.cameras_inside < 2;
  if (out.cameras_inside < 2 || !triangulate_with_uncertainty(a, Sa, pixels, sigma_px, pa) ||
      !triangulate_with_uncertainty(b, Sb, pixels, sigma_px, pb))
    return out;
  out.valid = true;
  // The same pixels: the centroid noise is common to both and cancels to first order.
  out.difference_m = pb.p_w - pa.p_w;
  out.cov_a = pa.cov_calibration;
  out.cov_b = pb.cov_calibration;
  out.chi2 = chi2_of(out.difference_m, out.cov_a + out.cov_b);
  out.inconsistent = out.chi2 > threshold;
  return out;
}

/// A mark's pixels by camera slot from the sightings (empty when a camera is not in the rig).
std::vector<SlotPixel> mark_pixels(const camera::RigCalibration& rig,
                                   const std::vector<BarSighting>& sightings, int mark_id) {
  std::vector<SlotPixel> out;
  for (const BarSighting& s : sightings) {
    if (s.mark_id != mark_id) continue;
    for (size_t i = 0; i < rig.cameras.size(); ++i)
      if (rig.cameras[i].camera_id == s.camera) out.push_back({static_cast<int>(i), s.pixel_px});
  }
  return out;
}

/// Length error of a bar through one calibration and its predicted standard uncertainty
/// (centroid of both marks + the calibration, common to both marks).
bool bar_error(const camera::RigCalibration& rig, const Eigen::MatrixXd& S,
               const std::vector<SlotPixel>& A, const std::vector<SlotPixel>& B, double sigma_px,
               double length_m, double& error_m, double& u_m) {
  PointUncertainty pa, pb;
  if (!triangulate_with_uncertainty(rig, S, A, sigma_px, pa) ||
      !triangulate_with_uncertainty(rig, S, B, sigma_px, pb))
    return false;
  const Vec3 d = pa.p_w - pb.p_w;
  const Vec3 n = d.normalized();
  const Eigen::RowVectorXd g = n.transpose() * (pa.sensitivity - pb.sensitivity);
  error_m = d.norm() - length_m;
  u_m = std::sqrt(n.dot((pa.cov_centroid + pb.cov_centroid) * n) + g * S * g.transpose());
  return true;
}

std::vector<BarComparison> compare_bars(const camera::RigCalibration& a, const Eigen::MatrixXd& Sa,
                                        const camera::RigCalibration& b, const Eigen::MatrixXd& Sb,
                                        const survey::ScaleBarSet& set,
                                        const std::vector<BarSighting>& sightings,
                                        double sigma_px) {
  std::vector<BarComparison> out;
  for (const survey::ScaleBar& bar : set.bars) {
    BarComparison c;
    c.id = bar.id;
    c.length_m = bar.length_m;
    c.u_length_m = bar.u_length_m;
    const auto A = mark_pixels(a, sightings, bar.mark_a), B = mark_pixels(a, sightings, bar.mark_b);
    if (A.size() < 2 || B.size() < 2) {
      c.reason = "mark " + std::to_string(A.size() < 2 ? bar.mark_a : bar.mark_b) +
                 " seen by fewer than 2 cameras";
    } else if (!bar_error(a, Sa, A, B, sigma_px, bar.length_m, c.error_a_m, c.u_a_m) ||
               !bar_error(b, Sb, A, B, sigma_px, bar.length_m, c.error_b_m, c.u_b_m)) {
      c.reason = "triangulation failed";
    } else {
      c.valid = true;
    }
    out.push_back(c);
  }
  return out;
}

/// True when the bars' normalised errors through one calibration pass their chi-square test
/// (sum of z^2 below the chi-square(bars) 99 % quantile); no valid bar: true.
bool bars_pass(const std::vector<BarComparison>& bars, bool use_a, int& count) {
  double chi2 = 0;
  count = 0;
  for (const BarComparison& c : bars) {
    if (!c.valid) continue;
    const double e = use_a ? c.error_a_m : c.error_b_m, u = use_a ? c.u_a_m : c.u_b_m;
    chi2 += e * e / (u * u + c.u_length_m * c.u_length_m);
    ++count;
  }
  return count == 0 ||
         chi2 <= uncertainty::chi_square_quantile(uncertainty::Probability(0.99),
                                                  uncertainty::DegreesOfFreedom(count));
}

/// Factor L with L L^T = S (eigenvectors scaled by sqrt of the eigenvalues above a relative
/// floor): the directions in which the calibration is uncertain.
Eigen::MatrixXd covariance_factor(const Eigen::MatrixXd& S) {
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(S);
  const Eigen::VectorXd& l = eig.eigenvalues();
  const double floor = 1e-12 * std::max(l.maxCoeff(), 1e-300);
  std::vector<Eigen::Index> keep;
  for (Eigen::Index i = 0; i < l.size(); ++i)
    if (l(i) > floor) keep.push_back(i);
  Eigen::MatrixXd L(S.rows(), static_cast<Eigen::Index>(keep.size()));
  for (size_t k = 0; k < keep.size(); ++k)
    L.col(static_cast<Eigen::Index>(k)) = eig.eigenvectors().col(keep[k]) * std::sqrt(l(keep[k]));
  return L;
}

/// Directions of the joint test weaker than this fraction of the strongest are left out: in
/// them the first-order model is dominated by the second-order terms (with 1e-6, pairs of
/// simulator calibrations drawn from their own stated covariance gave p = 0.002 and 0.0003;
/// with 1e-3, 0.03-0.85 over five pairs; docs/calibration.md).
constexpr double kJointRelativeSingularValue = 1e-3;

/// The whole volume's differences D tested jointly: D ~ N(0, M M^T) to first order with
/// M = [G_a L_a, G_b L_b] (the points share the calibration errors, so their chi-squares are
/// not independent); chi2 = |M^+ D|^2 over the singular values above
/// kJointRelativeSingularValue of the largest, dof = that rank.
void joint_test(const Eigen::VectorXd& D, const Eigen::MatrixXd& Ga, const Eigen::MatrixXd& La,
                const Eigen::MatrixXd& Gb, const Eigen::MatrixXd& Lb, ComparisonResult& r) {
  Eigen::MatrixXd M(D.size(), La.cols() + Lb.cols());
  M << Ga * La, Gb * Lb;
  const Eigen::BDCSVD<Eigen::MatrixXd> svd(M, Eigen::ComputeThinU);
  const Eigen::VectorXd& sv = svd.singularValues();
  const Eigen::VectorXd projected = svd.matrixU().transpose() * D;
  r.joint_chi2 = 0;
  r.joint_dof = 0;
  for (Eigen::Index i = 0; i < sv.size(); ++i) {
    if (!(sv(i) > kJointRelativeSingularValue * sv(0))) continue;
    r.joint_chi2 += projected(i) * projected(i) / (sv(i) * sv(i));
    ++r.joint_dof;
  }
  r.joint_p_value = r.joint_dof > 0 ? uncertainty::chi_square_survival(
                                          r.joint_chi2, uncertainty::DegreesOfFreedom(r.joint_dof))
                                    : 1.0;
}

std::string mm(double m) {
  std::ostringstream s;
  s.precision(3);
  s << m * 1e3 << " mm";
  return s.str();
}

void decide(ComparisonResult& r, const CompareOptions& o) {
  int bars = 0;
  const bool a_bars = bars_pass(r.bars, true, bars), b_bars = bars_pass(r.bars, false, bars);
  r.consistent = r.valid_points > 0 && r.joint_p_value >= o.false_alarm;
  std::ostringstream v;
  if (!r.consistent) {
    v << "INCONSISTENT: do not fly. The triangulated positions of " << o.origin_a << " and "
      << o.origin_b << " differ by more than both predicted uncertainties allow (joint test "
      << "over the working volume: chi2 " << r.joint_chi2 << " for " << r.joint_dof
      << " dof, p = " << r.joint_p_value << " < " << o.false_alarm << "; inconsistent at "
      << 100 * r.inconsistent_fraction << " % of the grid points; median |difference| "
      << mm(r.difference_m.p50) << ", max " << mm(r.difference_m.max)
      << "): at least one set is wrong or its covariance is too small. Find the cause "
         "(moved camera, board, registration) before either set is used.";
    r.better = '=';
  } else {
    const double ua = r.u_a_m.rms, ub = r.u_b_m.rms;
    r.better = ua < ub / 1.05 ? 'a' : (ub < ua / 1.05 ? 'b' : '=');
    v << "consistent: the sets agree within their predicted uncertainties (joint test over the "
         "working volume p = "
      << r.joint_p_value << "; " << 100 * r.inconsistent_fraction
      << " % of the grid points outside their own " << 100 * (1 - o.point_false_alarm)
      << " % ellipsoid). ";
    if (r.better == '=')
      v << "Neither is better: predicted uncertainty (rms over the volume) " << mm(ua) << " and "
        << mm(ub) << " (within 5 %).";
    else
      v << (r.better == 'a' ? o.origin_a : o.origin_b)
        << " is better: smaller predicted uncertainty (rms over the volume " << mm(ua) << " for "
        << o.origin_a << ", " << mm(ub) << " for " << o.origin_b << ").";
  }
  if (bars > 0 && (!a_bars || !b_bars)) {
    v << " Scale bars: " << (!a_bars ? o.origin_a + " " : "") << (!a_bars && !b_bars ? "and " : "")
      << (!b_bars ? o.origin_b + " " : "")
      << "fail the length test (errors larger than predicted): do not fly with "
      << (!a_bars && !b_bars ? "either." : "that set.");
    if (a_bars != b_bars && r.consistent) r.better = a_bars ? 'a' : 'b';
  }
  r.verdict = v.str();
}

/// A number for a message: 3 significant digits (an extrapolated difference can be 1e30).
std::string short_number(double v) {
  std::ostringstream s;
  s.precision(3);
  s << v;
  return s.str();
}

/// Marks the grid pixels inside both observed regions and summarises the differences there
/// (fitted, unfitted) and outside (fitted_outside).
void summarise_inside(const camera::RigCalibration& a, const camera::RigCalibration& b, size_t slot,
                      int min_points, CameraProjectionDifference& c) {
  std::vector<double> fitted, unfitted, outside;
  for (size_t i = 0; i < c.pixels.size(); ++i) {
    c.inside.push_back(inside_both(a, b, slot, c.pixels[i], min_points));
    c.outside_pixels += c.inside.back() ? 0 : 1;
    for (size_t d = 0; d < c.difference_px.size(); ++d) {
      (c.inside.back() ? fitted : outside).push_back(c.difference_px[d][i]);
      if (c.inside.back()) unfitted.push_back(c.difference_unfitted_px[d][i]);
    }
  }
  c.fitted = statistics_of(std::move(fitted));
  c.unfitted = statistics_of(std::move(unfitted));
  c.fitted_outside = statistics_of(std::move(outside));
}

}  // namespace

Statistics statistics_of(std::vector<double> values) {
  std::erase_if(values, [](double v) { return !std::isfinite(v); });
  Statistics s;
  s.count = static_cast<int>(values.size());
  if (values.empty()) return s;
  std::sort(values.begin(), values.end());
  double ss = 0;
  for (double v : values)
    ss += v * v;
  s.rms = std::sqrt(ss / static_cast<double>(values.size()));
  s.max = values.back();
  const auto rank = [&](double p) {  // nearest rank
    const auto k = static_cast<size_t>(std::ceil(p * static_cast<double>(values.size())));
    return values[std::clamp<size_t>(k, 1, values.size()) - 1];
  };
  s.p50 = rank(0.5);
  s.p95 = rank(0.95);
  s.p99 = rank(0.99);
  return s;
}

std::vector<double> default_working_distances(const camera::RigCalibration& rig,
                                              const std::string& origin) {
  Mat3 A = Mat3::Zero();
  Vec3 rhs = Vec3::Zero();
  for (const auto& c : rig.cameras) {
    const Vec3 axis = c.T_c_w.linear().row(2).transpose();
    const Mat3 P = Mat3::Identity() - axis * axis.transpose();
    A += P;
    rhs += P * camera_centre(c);
  }
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(A);
  if (rig.cameras.size() < 2 || !(eig.eigenvalues()(0) > 1e-6 * eig.eigenvalues()(2)))
    throw CalibrationError(origin +
                           ": cameras: the optical axes are (nearly) parallel, so no working "
                           "distance follows from the rig: give --distances");
  const Vec3 x = A.ldlt().solve(rhs);
  std::vector<double> depth;
  for (const auto& c : rig.cameras)
    depth.push_back((x - camera_centre(c)).dot(c.T_c_w.linear().row(2).transpose()));
  std::sort(depth.begin(), depth.end());
  const double d0 = depth[depth.size() / 2];
  if (!(d0 > 0))
    throw CalibrationError(origin +
                           ": cameras: the optical axes meet behind the cameras: give "
                           "--distances");
  return {0.5 * d0, d0, 1.5 * d0};
}

WorkingVolume default_working_volume(const camera::RigCalibration& rig,
                                     const std::vector<double>& distances,
                                     const std::string& origin) {
  Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (const auto& c : rig.cameras)
    for (double d : distances)
      for (const Vec2& q : pixel_grid(c.model.intrinsics(), 9, 9)) {
        const auto p = unproject_world(c, q, d);
        if (!p || visible_pixels(rig, *p).size() < 2) continue;
        lo = lo.cwiseMin(*p);
        hi = hi.cwiseMax(*p);
      }
  if (!(lo.array() <= hi.array()).all())
    throw CalibrationError(origin +
                           ": cameras: no point at the working distances is seen by 2 cameras: "
                           "give --volume or --distances");
  return {lo, hi};
}

std::vector<Vec3> volume_grid(const WorkingVolume& v, const std::array<int, 3>& n) {
  std::vector<Vec3> out;
  const auto at = [&](int axis, int i) {
    return n[axis] == 1 ? 0.5 * (v.min_w[axis] + v.max_w[axis])
                        : v.min_w[axis] + (v.max_w[axis] - v.min_w[axis]) * i / (n[axis] - 1);
  };
  for (int k = 0; k < n[2]; ++k)
    for (int j = 0; j < n[1]; ++j)
      for (int i = 0; i < n[0]; ++i)
        out.emplace_back(at(0, i), at(1, j), at(2, k));
  return out;
}

void check_same_rig(const camera::RigCalibration& a, const camera::RigCalibration& b,
                    const std::string& origin_a, const std::string& origin_b) {
  if (a.cameras.size() != b.cameras.size())
    throw CalibrationError(origin_b + ": /cameras: " + std::to_string(b.cameras.size()) +
                           " cameras, " + origin_a + " has " + std::to_string(a.cameras.size()) +
                           ": not calibrations of the same rig");
  for (size_t i = 0; i < a.cameras.size(); ++i) {
    const auto &ca = a.cameras[i], &cb = b.cameras[i];
    const std::string at = ": /cameras/" + std::to_string(i);
    if (ca.camera_id != cb.camera_id)
      throw CalibrationError(origin_b + at + "/camera_id: " + std::to_string(cb.camera_id) + ", " +
                             origin_a + " has " + std::to_string(ca.camera_id) +
                             " (same cameras in the same order needed)");
    const auto &ia = ca.model.intrinsics(), &ib = cb.model.intrinsics();
    if (ia.width != ib.width || ia.height != ib.height)
      throw CalibrationError(origin_b + at + "/image_size: " + std::to_string(ib.width) + "x" +
                             std::to_string(ib.height) + ", " + origin_a + " has " +
                             std::to_string(ia.width) + "x" + std::to_string(ia.height) +
                             " (camera " + std::to_string(ca.camera_id) + ")");
  }
}

ComparisonResult compare_calibrations(const camera::RigCalibration& a,
                                      const camera::RigCalibration& b, const CompareOptions& o_in,
                                      const survey::ScaleBarSet* bars,
                                      const std::vector<BarSighting>& bar_sightings) {
  check_same_rig(a, b, o_in.origin_a, o_in.origin_b);
  CompareOptions o = o_in;
  if (o.distances_m.empty()) o.distances_m = default_working_distances(a, o.origin_a);
  ComparisonResult r;
  region_warnings(a, o.origin_a, r.warnings);
  region_warnings(b, o.origin_b, r.warnings);
  r.distances_m = o.distances_m;
  r.volume = o.volume ? *o.volume : default_working_volume(a, o.distances_m, o.origin_a);

  std::vector<Vec3> p_wb_start;
  const auto samples = projection_samples(a, b, o, p_wb_start);
  r.T_b_a = fit_rigid_motion(b, samples, p_wb_start);
  for (size_t s = 0; s < a.cameras.size(); ++s) {
    CameraProjectionDifference c;
    c.camera_id = a.cameras[s].camera_id;
    c.columns = o.grid_columns;
    c.rows = o.grid_rows;
    c.pixels = pixel_grid(a.cameras[s].model.intrinsics(), o.grid_columns, o.grid_rows);
    const int slot = static_cast<int>(s);
    c.difference_px = grid_differences(a, b, slot, c.pixels, o.distances_m, r.T_b_a);
    c.difference_unfitted_px =
        grid_differences(a, b, slot, c.pixels, o.distances_m, Transform::Identity());
    summarise_inside(a, b, s, o.min_points_per_cell, c);
    if (c.outside_pixels > 0)
      r.warnings.push_back(
          "camera " + std::to_string(c.camera_id) + ": " + std::to_string(c.outside_pixels) +
          " of " + std::to_string(c.pixels.size()) +
          " projection grid pixels lie outside the observed region of " + o.origin_a + " or " +
          o.origin_b + ": the models are evaluated beyond their data there (max difference " +
          short_number(c.fitted_outside.max) + " px, marked, left out of the statistics)");
    r.cameras.push_back(std::move(c));
  }

  const Eigen::MatrixXd Sa = a.full_joint_covariance(), Sb = b.full_joint_covariance();
  r.chi2_threshold = uncertainty::chi_square_quantile(
      uncertainty::Probability(1 - o.point_false_alarm), uncertainty::DegreesOfFreedom(3));
  std::vector<double> diff, ua, ub;
  std::vector<PointUncertainty> all_a, all_b;
  int inconsistent = 0;
  for (const Vec3& x : volume_grid(r.volume, o.volume_points)) {
    PointUncertainty pa, pb;
    r.points.push_back(compare_point(a, Sa, b, Sb, x, o, r.chi2_threshold, pa, pb));
    const VolumePointDifference& p = r.points.back();
    if (!p.valid) {
      ++(p.outside ? r.outside_points : r.unseen_points);
      continue;
    }
    all_a.push_back(std::move(pa));
    all_b.push_back(std::move(pb));
    ++r.valid_points;
    inconsistent += p.inconsistent ? 1 : 0;
    diff.push_back(p.difference_m.norm());
    ua.push_back(std::sqrt(p.cov_a.trace()));
    ub.push_back(std::sqrt(p.cov_b.trace()));
  }
  if (r.outside_points > 0)
    r.warnings.push_back(std::to_string(r.outside_points) +
                         " volume points are seen by >= 2 cameras only outside the observed "
                         "regions: left out (a triangulation there would extrapolate the models)");
  r.inconsistent_fraction = r.valid_points ? double(inconsistent) / r.valid_points : 0.0;
  if (r.valid_points > 0) {
    const Eigen::Index n = r.valid_points, cols = Sa.cols();
    Eigen::VectorXd D(3 * n);
    Eigen::MatrixXd Ga(3 * n, cols), Gb(3 * n, cols);
    for (Eigen::Index i = 0; i < n; ++i) {
      D.segment<3>(3 * i) = all_b[static_cast<size_t>(i)].p_w - all_a[static_cast<size_t>(i)].p_w;
      Ga.middleRows<3>(3 * i) = all_a[static_cast<size_t>(i)].sensitivity;
      Gb.middleRows<3>(3 * i) = all_b[static_cast<size_t>(i)].sensitivity;
    }
    joint_test(D, Ga, covariance_factor(Sa), Gb, covariance_factor(Sb), r);
  }
  r.difference_m = statistics_of(diff);
  r.u_a_m = statistics_of(ua);
  r.u_b_m = statistics_of(ub);
  if (bars != nullptr) r.bars = compare_bars(a, Sa, b, Sb, *bars, bar_sightings, o.sigma_px);
  decide(r, o);
  return r;
}

std::vector<Vec2> projection_difference(const camera::CameraModel& a, const camera::CameraModel& b,
                                        const std::vector<Vec2>& pixels,
                                        const std::vector<double>& fit_distances_m,
                                        double distance_m) {
  camera::RigCalibration rig_a, rig_b;  // one camera each, T_c_w = identity, no regions
  rig_a.cameras.resize(1);
  rig_b.cameras.resize(1);
  rig_a.cameras[0].model = a;
  rig_b.cameras[0].model = b;
  std::vector<ProjectionSample> samples;
  std::vector<Vec3> p_wb_start;
  for (double d : fit_distances_m)
    for (const Vec2& q : pixels) {
      const auto p_wa = unproject_world(rig_a.cameras[0], q, d);
      if (!p_wa) continue;
      samples.push_back({0, q, *p_wa});
      p_wb_start.push_back(unproject_world(rig_b.cameras[0], q, d).value_or(Vec3::Constant(kNaN)));
    }
  const Transform T_b_a = fit_rigid_motion(rig_b, samples, p_wb_start);
  std::vector<Vec2> out;
  for (const Vec2& q : pixels)
    out.push_back(difference_vector(rig_a.cameras[0], rig_b.cameras[0], q, distance_m, T_b_a));
  return out;
}

UncertaintyMap uncertainty_map(const camera::RigCalibration& rig, const UncertaintyMapOptions& o) {
  UncertaintyMap map;
  map.n = o.volume_points;
  if (o.volume) {
    map.volume = *o.volume;
  } else {
    const auto distances =
        o.distances_m.empty() ? default_working_distances(rig, o.origin) : o.distances_m;
    map.volume = default_working_volume(rig, distances, o.origin);
  }
  map.covariance_source = rig.joint_covariance.size() != 0
                              ? "joint covariance (file version 2, cross terms included)"
                              : "per-camera blocks (no joint covariance in the file)";
  const Eigen::MatrixXd S = rig.full_joint_covariance();
  for (const Vec3& x : volume_grid(map.volume, map.n)) {
    UncertaintyMapPoint p;
    p.p_w = x;
    const auto pixels = visible_pixels(rig, x);
    p.cameras = static_cast<int>(pixels.size());
    PointUncertainty u;
    if (triangulate_with_uncertainty(rig, S, pixels, o.sigma_px, u)) {
      p.valid = true;
      p.cov_centroid = u.cov_centroid;
      p.cov_calibration = u.cov_calibration;
    }
    map.points.push_back(p);
  }
  return map;
}

}  // namespace storetrack::calib
