// Release time t0: a chi-square test against the captive hypothesis, then a least-squares fit
// of the ejector's uniform-acceleration onset (method and references: release_time.hpp).
#include "storetrack/smooth/release_time.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Cholesky>

#include "storetrack/uncertainty/spd_inverse.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::smooth {

namespace {

using geometry::Mat3;
using geometry::Vec3;
using Shared3 = Eigen::Matrix<double, 3, Eigen::Dynamic>;
using Mat7 = Eigen::Matrix<double, 7, 7>;

/// A solved position: time since the first solved exposure [s], value, noise weight, shared
/// loadings (all padded to the same columns).
struct Point {
  double t = 0;
  Vec3 y = Vec3::Zero();
  Mat3 noise = Mat3::Zero(), weight = Mat3::Zero();
  Shared3 shared;
};

std::vector<Point> solved_positions(std::span<const PoseMeasurement> ms, time::TaiNs& t_base) {
  Eigen::Index cols = 0;
  for (const PoseMeasurement& m : ms)
    if (m.solved) cols = std::max(cols, m.shared.cols());
  std::vector<Point> out;
  for (const PoseMeasurement& m : ms) {
    if (!m.solved) continue;
    if (out.empty()) t_base = m.t_ns;
    Point p;
    p.t = static_cast<double>(m.t_ns - t_base) * 1e-9;
    p.y = m.T_p_s.translation();
    p.noise = m.cov_noise.bottomRightCorner<3, 3>();  // (r, t) order: translation last
    if (!uncertainty::inverse_spd<3>(p.noise, p.weight)) continue;
    p.shared = Shared3::Zero(3, cols);
    p.shared.leftCols(m.shared.cols()) = m.shared.bottomRows<3>();
    out.push_back(std::move(p));
  }
  return out;
}

/// The first point after the captive reference whose displacement from it is significant;
/// -1 when none (r.reason says why).
int captive_alarm(const std::vector<Point>& pts, const ReleaseTimeConfig& c, ReleaseTime& r) {
  Mat3 info = Mat3::Zero();
  Vec3 sum = Vec3::Zero();
  Shared3 sum_shared = Shared3::Zero(3, pts.front().shared.cols());
  std::size_t k = 0;
  for (; k < pts.size() && pts[k].t <= c.captive_reference_s; ++k) {
    info += pts[k].weight;
    sum += pts[k].weight * pts[k].y;
    sum_shared += pts[k].weight * pts[k].shared;
  }
  Mat3 ref_cov;
  if (!uncertainty::inverse_spd<3>(info, ref_cov)) {
    r.reason = "no captive reference (no solved pose in the first captive_reference_s)";
    return -1;
  }
  const Vec3 ref = ref_cov * sum;
  const Shared3 ref_shared = ref_cov * sum_shared;
  r.alarm_threshold = uncertainty::chi_square_quantile(uncertainty::Probability(1 - c.false_alarm),
                                                       uncertainty::DegreesOfFreedom(3));
  for (; k < pts.size(); ++k) {
    const Shared3 change = pts[k].shared - ref_shared;
    const Mat3 S = pts[k].noise + ref_cov + change * change.transpose();
    Mat3 S_inv;
    if (!uncertainty::inverse_spd<3>(S, S_inv)) continue;
    const Vec3 d = pts[k].y - ref;
    const double chi2 = d.dot(S_inv * d);
    if (chi2 > r.alarm_threshold) {
      r.alarm_chi2 = chi2;
      return static_cast<int>(k);
    }
  }
  r.reason = "no motion against the captive hypothesis (chi-square test, false alarm " +
             std::to_string(c.false_alarm) + " per exposure)";
  return -1;
}

/// The onset fit's data, stacked (3 rows per point): positions, the noise covariance (block
/// diagonal), the shared loadings, and the weight: the inverse of the joint covariance, noise
/// plus shared. The shared errors are common to all points but their loadings are not: when a
/// camera's observations are lost live (dropped late by the aligner), its calibration errors
/// stop entering those exposures' poses and the points move against each other by up to the
/// shared u, far beyond the noise (issue 26). Only their constant part is absorbed by c.
struct FitData {
  std::vector<double> t;
  Eigen::VectorXd y;
  Eigen::MatrixXd noise, shared, weight;
};

bool stack_fit_data(std::span<const Point> pts, FitData& f) {
  const auto n = static_cast<Eigen::Index>(pts.size());
  f.t.clear();
  f.y.resize(3 * n);
  f.noise = Eigen::MatrixXd::Zero(3 * n, 3 * n);
  f.shared.resize(3 * n, pts.front().shared.cols());
  for (Eigen::Index k = 0; k < n; ++k) {
    const Point& p = pts[static_cast<std::size_t>(k)];
    f.t.push_back(p.t);
    f.y.segment<3>(3 * k) = p.y;
    f.noise.block<3, 3>(3 * k, 3 * k) = p.noise;
    f.shared.middleRows<3>(3 * k) = p.shared;
  }
  const Eigen::MatrixXd cov = f.noise + f.shared * f.shared.transpose();
  return uncertainty::inverse_spd<Eigen::Dynamic>(cov, f.weight);
}

/// The onset model's Jacobian for a given t0 (columns c, a, t0; rows 3 per point).
Eigen::Matrix<double, Eigen::Dynamic, 7> onset_jacobian(const FitData& f, double t0,
                                                        const Vec3& a) {
  Eigen::Matrix<double, Eigen::Dynamic, 7> J(3 * static_cast<Eigen::Index>(f.t.size()), 7);
  for (std::size_t k = 0; k < f.t.size(); ++k) {
    const double tau = std::max(0.0, f.t[k] - t0);
    J.middleRows<3>(3 * static_cast<Eigen::Index>(k)) << Mat3::Identity(),
        0.5 * tau * tau * Mat3::Identity(), -a * tau;
  }
  return J;
}

/// The onset model's linear part for a given t0: c and a by generalised least squares; returns
/// the chi-square (infinite when c and a are not determined).
double profile_chi2(const FitData& f, double t0, Vec3& c, Vec3& a) {
  const Eigen::Matrix<double, Eigen::Dynamic, 6> X =
      onset_jacobian(f, t0, Vec3::Zero()).leftCols<6>();
  const Eigen::Matrix<double, Eigen::Dynamic, 6> WX = f.weight * X;
  const Eigen::Matrix<double, 6, 6> A = X.transpose() * WX;
  const Eigen::LDLT<Eigen::Matrix<double, 6, 6>> ldlt(A);
  if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().array() > 0).all())
    return std::numeric_limits<double>::infinity();
  const Eigen::Matrix<double, 6, 1> x = ldlt.solve(WX.transpose() * f.y);
  c = x.head<3>();
  a = x.tail<3>();
  const Eigen::VectorXd r = f.y - X * x;
  return r.dot(f.weight * r);
}

/// t0 minimising the profile chi-square over [lo, hi]: a 10 us grid, then golden section
/// inside the best cell's neighbours (the profile is smooth: the model is C1 in t0).
double minimise_profile(const FitData& f, double lo, double hi) {
  Vec3 c, a;
  constexpr double kGrid = 1e-5;
  double best = lo, best_chi2 = std::numeric_limits<double>::infinity();
  for (double t = lo; t <= hi; t += kGrid)
    if (const double chi2 = profile_chi2(f, t, c, a); chi2 < best_chi2) {
      best_chi2 = chi2;
      best = t;
    }
  const double phi = 0.5 * (std::sqrt(5.0) - 1);
  double x0 = std::max(lo, best - kGrid), x3 = std::min(hi, best + kGrid);
  double x1 = x3 - phi * (x3 - x0), x2 = x0 + phi * (x3 - x0);
  double f1 = profile_chi2(f, x1, c, a), f2 = profile_chi2(f, x2, c, a);
  while (x3 - x0 > 1e-9) {
    if (f1 < f2) {
      x3 = x2, x2 = x1, f2 = f1;
      x1 = x3 - phi * (x3 - x0);
      f1 = profile_chi2(f, x1, c, a);
    } else {
      x0 = x1, x1 = x2, f1 = f2;
      x2 = x0 + phi * (x3 - x0);
      f2 = profile_chi2(f, x2, c, a);
    }
  }
  const double t = 0.5 * (x0 + x3);
  return profile_chi2(f, t, c, a) <= best_chi2 ? t : best;
}

/// u(t0) at the solution: the estimate's linear map m = [(J^T W J)^-1 J^T W] (t0's row) applied
/// to the noise covariance (noise part) and to the shared loadings (shared part); their sum is
/// (J^T W J)^-1's t0 entry. False when not determined.
bool onset_uncertainty(const FitData& f, double t0, const Vec3& a, ReleaseTime& r) {
  const Eigen::Matrix<double, Eigen::Dynamic, 7> J = onset_jacobian(f, t0, a);
  const Eigen::Matrix<double, Eigen::Dynamic, 7> WJ = f.weight * J;
  Mat7 H_inv;
  if (!uncertainty::inverse_spd<7>(Mat7(J.transpose() * WJ), H_inv)) return false;
  const Eigen::RowVectorXd m = H_inv.row(6) * WJ.transpose();
  r.u_noise_s = std::sqrt(m.dot(f.noise * m.transpose()));
  r.u_shared_s = (m * f.shared).norm();
  r.u_t0_s = std::hypot(r.u_noise_s, r.u_shared_s);
  return true;
}

}  // namespace

ReleaseTime estimate_release_time(std::span<const PoseMeasurement> measurements,
                                  const ReleaseTimeConfig& config) {
  ReleaseTime r;
  time::TaiNs t_base = 0;
  const std::vector<Point> pts = solved_positions(measurements, t_base);
  if (pts.empty()) {
    r.reason = "no solved store pose";
    return r;
  }
  const int alarm = captive_alarm(pts, config, r);
  if (alarm < 0) return r;
  const double t_alarm = pts[static_cast<std::size_t>(alarm)].t;
  r.alarm_ns = t_base + static_cast<time::TaiNs>(std::llround(t_alarm * 1e9));
  // The fit's data: lookback before the alarm (captive: c), onset_window after (moving: a, t0).
  auto first = std::lower_bound(pts.begin(), pts.end(), t_alarm - config.lookback_s,
                                [](const Point& p, double t) { return p.t < t; });
  auto last = std::upper_bound(pts.begin(), pts.end(), t_alarm + config.onset_window_s,
                               [](double t, const Point& p) { return t < p.t; });
  FitData fit;
  if (!stack_fit_data(std::span<const Point>(&*first, static_cast<std::size_t>(last - first)),
                      fit)) {
    r.reason = "the onset fit's covariance is not positive definite";
    return r;
  }
  const double t0 = minimise_profile(fit, std::max(0.0, t_alarm - config.lookback_s), t_alarm);
  Vec3 c, a;
  r.fit_chi2 = profile_chi2(fit, t0, c, a);
  r.fit_dof = 3 * static_cast<int>(fit.t.size()) - 7;
  if (!std::isfinite(r.fit_chi2) || r.fit_dof <= 0 || !onset_uncertainty(fit, t0, a, r)) {
    r.reason = "the onset fit does not determine t0 (too few solved poses around the alarm)";
    return r;
  }
  // A t0 inside the captive reference means the store moved there (the recording starts too
  // late); a fit the model does not explain (chi-square beyond the test's false-alarm quantile)
  // has no honest u(t0). Either way: no t0.
  if (t0 <= config.captive_reference_s) {
    r.reason = "the release lies inside the captive reference (the recording starts too late)";
    return r;
  }
  if (r.fit_chi2 >
      uncertainty::chi_square_quantile(uncertainty::Probability(1 - config.false_alarm),
                                       uncertainty::DegreesOfFreedom(r.fit_dof))) {
    r.reason = "the onset model does not fit the data (chi-square " + std::to_string(r.fit_chi2) +
               " for " + std::to_string(r.fit_dof) + " degrees of freedom)";
    return r;
  }
  r.detected = true;
  r.t0_ns = t_base + static_cast<time::TaiNs>(std::llround(t0 * 1e9));
  r.onset_accel_p = a;
  return r;
}

}  // namespace storetrack::smooth
