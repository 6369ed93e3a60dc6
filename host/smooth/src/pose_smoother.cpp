// Rauch-Tung-Striebel fixed-interval smoother (Rauch, Tung, Striebel, "Maximum likelihood
// estimates of linear dynamic systems", AIAA Journal 3(8), 1965) of the store pose, with the
// shared (calibration + survey) error carried through the same linear recursions as loadings.
// Method and derivations: docs/post-processing.md, "Smoothed trajectory".
#include <algorithm>
#include <cmath>

#include "storetrack/smooth/pose_smoother.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::smooth {

namespace {

using geometry::Mat3;
using geometry::Mat6;
using geometry::Vec3;
using geometry::Vec6;
using Gain = Eigen::Matrix<double, kStateSize, 6>;

double seconds(time::TaiNs a, time::TaiNs b) {
  return static_cast<double>(a - b) * 1e-9;
}

/// One exposure of a segment: what the backward pass needs of the forward filter, and no more
/// (issue 26: the smoother's memory is per exposure). The filtered shared loadings E (18 x the
/// shared factors, the largest part) are kept in the output state's `shared`, which the backward
/// pass overwrites with the smoothed ones; the interval's transition, process covariance and
/// prediction are recomputed there, by the same functions, from the times and the step flag.
struct Step {
  const PoseMeasurement* m = nullptr;
  Vec3 theta_measured = Vec3::Zero();  ///< accumulated attitude of the last solved pose
  const PoseMeasurement* attitude_reference = nullptr;  ///< that solved pose
  StateVector x = StateVector::Zero();                  ///< filtered
  StateMatrix P = StateMatrix::Zero();                  ///< filtered
};

/// The process model of one interval: transition and process covariance.
struct Interval {
  StateMatrix F, Q;
};

/// The prediction through an interval, shared by the forward and the backward pass so that both
/// see the same rounding.
struct Prediction {
  StateVector x;
  StateMatrix P;
};

/// P^-1 of a covariance whose diagonal spans many decades (a diffuse prior beside a
/// sub-millimetre pose): inverted on its correlation matrix D P D, D = diag(P)^-1/2, which keeps
/// the Cholesky factor's relative error at cond(correlation) eps.
bool inverse_scaled(const StateMatrix& P, StateMatrix& out) {
  const StateVector d = P.diagonal().cwiseSqrt().cwiseInverse();
  if (!d.allFinite()) return false;
  StateMatrix corr = d.asDiagonal() * P * d.asDiagonal();
  corr = 0.5 * (corr + corr.transpose()).eval();
  StateMatrix inv;
  if (!uncertainty::inverse_spd<kStateSize>(corr, inv)) return false;
  out = d.asDiagonal() * inv * d.asDiagonal();
  return true;
}

SharedLoadings6 padded(const SharedLoadings6& M, Eigen::Index cols) {
  SharedLoadings6 out = SharedLoadings6::Zero(6, cols);
  out.leftCols(std::min(cols, M.cols())) = M.leftCols(std::min(cols, M.cols()));
  return out;
}

/// Kalman update of `s` from its prediction `pred` with its solved pose; `E`: the predicted
/// shared loadings, updated in place. False when S is not positive definite (`s` and `E` keep
/// the prediction). `nis`: the innovation's chi-square (6 degrees of freedom under the model).
bool update(const Prediction& pred, Step& s, SharedLoadings& E, Eigen::Index shared_cols,
            double& nis) {
  const PoseMeasurement& m = *s.m;
  Mat6 S_inv;
  const Mat6 S = pred.P.topLeftCorner<6, 6>() + m.cov_noise;
  if (!uncertainty::inverse_spd<6>(0.5 * (S + S.transpose()), S_inv)) return false;
  const Gain K = pred.P.leftCols<6>() * S_inv;
  Vec6 y;
  y << s.theta_measured, m.T_p_s.translation();
  const Vec6 innovation = y - pred.x.head<6>();
  // The step test's chi-square is over the innovation's whole covariance: its noise part S and
  // the change of the shared error since the prediction, (M_k - H F E_k-1) z (a mark excluded
  // or a camera lost moves the calibration error of the pose; that is no acceleration step).
  const SharedLoadings6 M = padded(m.shared, shared_cols);
  const SharedLoadings6 D = M - E.topRows<6>();
  const Mat6 S_full = S + D * D.transpose();
  Mat6 S_full_inv;
  nis = uncertainty::inverse_spd<6>(0.5 * (S_full + S_full.transpose()), S_full_inv)
            ? innovation.dot(S_full_inv * innovation)
            : 0.0;
  s.x = pred.x + K * innovation;
  StateMatrix I_KH = StateMatrix::Identity();
  I_KH.leftCols<6>() -= K;
  // Joseph form: symmetric and positive semi-definite whatever the rounding.
  s.P = I_KH * pred.P * I_KH.transpose() + K * m.cov_noise * K.transpose();
  E = I_KH * E + K * M;
  return true;
}

void init_first(Step& s, const SmootherConfig& c, Eigen::Index shared_cols, SharedLoadings& E) {
  const PoseMeasurement& m = *s.m;
  s.x.setZero();
  s.x.segment<3>(kPosition) = m.T_p_s.translation();
  s.P.setZero();
  s.P.topLeftCorner<6, 6>() = m.cov_noise;
  s.P.block<3, 3>(kAngularRate, kAngularRate) =
      Mat3::Identity() * c.prior_angular_rate_rad_s * c.prior_angular_rate_rad_s;
  s.P.block<3, 3>(kVelocity, kVelocity) =
      Mat3::Identity() * c.prior_velocity_m_s * c.prior_velocity_m_s;
  s.P.block<3, 3>(kAcceleration, kAcceleration) =
      Mat3::Identity() * c.prior_accel_m_s2 * c.prior_accel_m_s2;
  s.P.block<3, 3>(kAngularAccel, kAngularAccel) =
      Mat3::Identity() * c.prior_angular_accel_rad_s2 * c.prior_angular_accel_rad_s2;
  E = SharedLoadings::Zero(kStateSize, shared_cols);
  E.topRows<6>() = padded(m.shared, shared_cols);
}

/// The interval from `prev` to `s`; `jump`: it holds an acceleration step.
Interval interval_model(const Step& prev, const Step& s, const SmootherConfig& c, bool jump) {
  const double dt = seconds(s.m->t_ns, prev.m->t_ns);
  Interval iv;
  StateMatrix Q_jump, F_unused;
  process_model(
      dt, c.aero_accel_sigma_m_s2 * c.aero_accel_sigma_m_s2 / c.flow_field_time_s,
      c.aero_angular_accel_sigma_rad_s2 * c.aero_angular_accel_sigma_rad_s2 / c.flow_field_time_s,
      iv.F, iv.Q);
  if (jump) {
    // A step of the acceleration at a uniformly distributed instant of the interval.
    process_model(dt, c.accel_step_m_s2 * c.accel_step_m_s2 / dt,
                  c.angular_accel_step_rad_s2 * c.angular_accel_step_rad_s2 / dt, F_unused, Q_jump);
    iv.Q += Q_jump;
  }
  return iv;
}

Prediction predict(const Interval& iv, const Step& prev) {
  Prediction out;
  out.x = iv.F * prev.x;
  out.P = iv.F * prev.P * iv.F.transpose() + iv.Q;
  return out;
}

/// Forward filter over one segment (first and last exposures solved), with acceleration steps
/// in the intervals ending at the exposures marked in `jump`; the filtered shared loadings go to
/// `states[k].shared`. `alarm`: the first exposure whose innovation chi-square exceeds
/// `nis_limit` and whose interval holds no step yet, else -1.
std::vector<Step> filter(std::span<const PoseMeasurement> seg, const SmootherConfig& c,
                         Eigen::Index shared_cols, const std::vector<char>& jump, double nis_limit,
                         std::span<SmoothedState> states, int& alarm, SmootherCounters& counters) {
  std::vector<Step> steps(seg.size());
  steps[0].m = &seg[0];
  steps[0].attitude_reference = &seg[0];
  init_first(steps[0], c, shared_cols, states[0].shared);
  alarm = -1;
  for (std::size_t k = 1; k < seg.size(); ++k) {
    const Step& prev = steps[k - 1];
    Step& s = steps[k];
    s.m = &seg[k];
    const Interval iv = interval_model(prev, s, c, jump[k] != 0);
    const Prediction pred = predict(iv, prev);
    s.x = pred.x;
    s.P = pred.P;
    SharedLoadings& E = states[k].shared;
    E = iv.F * states[k - 1].shared;
    s.theta_measured = prev.theta_measured;
    s.attitude_reference = prev.attitude_reference;
    if (!s.m->solved) continue;
    // The attitude accumulates the solved poses' increments (left, pylon frame).
    s.theta_measured += geometry::rotvec_from_rotation(
        s.m->T_p_s.linear() * prev.attitude_reference->T_p_s.linear().transpose());
    s.attitude_reference = s.m;
    double nis = 0;
    if (!update(pred, s, E, shared_cols, nis))
      ++counters.update_failures;
    else if (alarm < 0 && nis > nis_limit && !jump[k])
      alarm = static_cast<int>(k);
  }
  return steps;
}

/// The forward filter, re-run while it detects acceleration steps: each alarm models a step in
/// the two intervals before the alarming exposure (a step late in the interval before it shows
/// only one exposure later).
std::vector<Step> filter_with_steps(std::span<const PoseMeasurement> seg, const SmootherConfig& c,
                                    Eigen::Index shared_cols, std::vector<char>& jump,
                                    std::span<SmoothedState> states, SmootherCounters& counters) {
  const double nis_limit = uncertainty::chi_square_quantile(
      uncertainty::Probability(1 - c.step_false_alarm), uncertainty::DegreesOfFreedom(6));
  jump.assign(seg.size(), 0);
  int alarm = -1;
  std::vector<Step> steps = filter(seg, c, shared_cols, jump, nis_limit, states, alarm, counters);
  for (int rerun = 0; alarm > 0 && rerun < 64; ++rerun) {
    jump[static_cast<std::size_t>(alarm)] = 1;
    if (alarm > 1) jump[static_cast<std::size_t>(alarm - 1)] = 1;
    steps = filter(seg, c, shared_cols, jump, nis_limit, states, alarm, counters);
  }
  for (std::size_t k = 0; k < seg.size(); ++k) {
    counters.steps += jump[k] ? 1 : 0;
    if (k > 0 && !seg[k].solved) ++counters.predicted;
    if (seg[k].solved) ++counters.measurements;
  }
  return steps;
}

/// The smoothed state `x`, `P` of step `s` into `out` (whose `shared` the caller has set).
void fill_output(const Step& s, const StateVector& x, const StateMatrix& P, int segment,
                 SmoothedState& out) {
  out.t_ns = s.m->t_ns;
  out.segment = segment;
  out.measured = s.m->solved;
  // Exp(theta_hat - theta_measured) about the last solved attitude (this exposure's own when
  // it was solved).
  const geometry::Transform& ref = s.attitude_reference->T_p_s;
  out.T_p_s.linear() =
      geometry::rotation_from_rotvec(x.segment<3>(kAttitude) - s.theta_measured) * ref.linear();
  out.T_p_s.translation() = x.segment<3>(kPosition);
  out.angular_rate_p = x.segment<3>(kAngularRate);
  out.velocity_p = x.segment<3>(kVelocity);
  out.angular_accel_p = x.segment<3>(kAngularAccel);
  out.accel_p = x.segment<3>(kAcceleration);
  out.cov_noise = 0.5 * (P + P.transpose());
  if (s.m->solved) out.cov_noise_per_exposure = s.m->cov_noise;
}

/// Backward (RTS) pass over the filtered `steps`, into `states` (which hold the filtered shared
/// loadings and get the smoothed ones).
void smooth_back(const std::vector<Step>& steps, const std::vector<char>& jump,
                 const SmootherConfig& c, int segment, std::span<SmoothedState> states,
                 SmootherCounters& counters) {
  const std::size_t n = steps.size();
  StateVector x_next = steps[n - 1].x;
  StateMatrix P_next = steps[n - 1].P;
  fill_output(steps[n - 1], x_next, P_next, segment, states[n - 1]);
  for (std::size_t k = n - 1; k-- > 0;) {
    const Step& s = steps[k];
    const Interval after = interval_model(s, steps[k + 1], c, jump[k + 1] != 0);
    const Prediction pred = predict(after, s);
    StateMatrix P_pred_inv;
    if (!inverse_scaled(pred.P, P_pred_inv)) {
      ++counters.update_failures;
      P_pred_inv.setZero();  // no smoothing gain: the filtered estimate
    }
    const StateMatrix C = s.P * after.F.transpose() * P_pred_inv;
    const StateVector x = s.x + C * (x_next - pred.x);
    // P + C (P_next - P_pred) C^T, written as a sum of positive semi-definite terms (equal for
    // the exact gain, P_pred = F P F^T + Q): rounding in C cannot make it indefinite.
    StateMatrix I_CF = StateMatrix::Identity() - C * after.F;
    const StateMatrix P = I_CF * s.P * I_CF.transpose() + C * (after.Q + P_next) * C.transpose();
    // The shared error of the predicted state is F E (the next one's before its update).
    const SharedLoadings& E_filtered = states[k].shared;
    SharedLoadings E = E_filtered + C * (states[k + 1].shared - after.F * E_filtered);
    states[k].shared = std::move(E);
    fill_output(s, x, P, segment, states[k]);
    x_next = x;
    P_next = P;
  }
  for (std::size_t k = 0; k < n; ++k)
    states[k].step = jump[k] != 0;
}

}  // namespace

void process_model(double dt, double jerk_psd, double angular_jerk_psd, StateMatrix& F,
                   StateMatrix& Q) {
  F.setIdentity();
  Q.setZero();
  const Mat3 I = Mat3::Identity();
  const double dt2 = dt * dt, dt3 = dt2 * dt, dt4 = dt3 * dt, dt5 = dt4 * dt;
  // Constant acceleration, white jerk (CWPA, Bar-Shalom 6.2.3), per axis of the attitude
  // (theta, omega, alpha) and of the position (p, v, a).
  const double q[3][3] = {
      {dt5 / 20, dt4 / 8, dt3 / 6}, {dt4 / 8, dt3 / 3, dt2 / 2}, {dt3 / 6, dt2 / 2, dt}};
  const int rotation[3] = {kAttitude, kAngularRate, kAngularAccel};
  const int translation[3] = {kPosition, kVelocity, kAcceleration};
  for (const auto& [blocks, psd] :
       {std::pair{rotation, angular_jerk_psd}, std::pair{translation, jerk_psd}}) {
    F.block<3, 3>(blocks[0], blocks[1]) = dt * I;
    F.block<3, 3>(blocks[0], blocks[2]) = dt2 / 2 * I;
    F.block<3, 3>(blocks[1], blocks[2]) = dt * I;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        Q.block<3, 3>(blocks[i], blocks[j]) = psd * q[i][j] * I;
  }
}

std::vector<SmoothedState> smooth_trajectory(std::span<const PoseMeasurement> measurements,
                                             const SmootherConfig& config,
                                             SmootherCounters* counters) {
  SmootherCounters local;
  SmootherCounters& c = counters ? *counters : local;
  Eigen::Index shared_cols = 0;
  for (const PoseMeasurement& m : measurements)
    if (m.solved) shared_cols = std::max(shared_cols, m.shared.cols());
  std::vector<SmoothedState> out;
  const std::size_t n = measurements.size();
  // At most one state per exposure; reserved so that no segment's states move while filled.
  out.reserve(n);
  std::size_t k = 0;
  int segment = 0;
  while (k < n) {
    if (!measurements[k].solved) {
      ++c.left_out;
      ++k;
      continue;
    }
    // [k, last]: solved at both ends, no solved pose further than max_gap_s from the previous.
    std::size_t last = k;
    for (std::size_t j = k + 1; j < n; ++j) {
      if (seconds(measurements[j].t_ns, measurements[last].t_ns) > config.max_gap_s) break;
      if (measurements[j].solved) last = j;
    }
    if (last == k) {
      ++c.left_out;  // one solved pose: no rate
      ++k;
      continue;
    }
    const std::size_t first_state = out.size(), count = last - k + 1;
    out.resize(first_state + count);
    const std::span<SmoothedState> states = std::span(out).subspan(first_state, count);
    std::vector<char> jump;
    const std::vector<Step> steps =
        filter_with_steps(measurements.subspan(k, count), config, shared_cols, jump, states, c);
    smooth_back(steps, jump, config, segment++, states, c);
    ++c.segments;
    k = last + 1;
  }
  return out;
}

}  // namespace storetrack::smooth
