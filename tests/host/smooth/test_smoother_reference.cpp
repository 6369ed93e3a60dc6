// The fixed-interval smoother's results are unchanged by the issue-26 memory reduction (the
// backward pass now keeps only the filtered state, covariance and shared loadings per exposure,
// recomputing the interval's transition, process noise and prediction): its states, noise
// covariances and shared loadings are compared with the algorithm as it was before (main
// a5aab6d, host/smooth/src/pose_smoother.cpp, copied below unchanged but for its names and the
// cov_shared member it no longer has), to 1e-12 relative, on a main-job-like input: the
// processor's solutions of the simulated store separation (captive, ejector stroke, free flight:
// acceleration steps detected, so the filter is re-run), with two gaps cut into it (one
// predicted through, one that splits the segment).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "sim_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/smooth/pose_smoother.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::smooth {
namespace before_issue26_memory {
namespace {

void process_model_before(double dt, double jerk_psd, double angular_jerk_psd, StateMatrix& F,
                          StateMatrix& Q);

using geometry::Mat3;
using geometry::Mat6;
using geometry::Vec3;
using geometry::Vec6;
using Gain = Eigen::Matrix<double, kStateSize, 6>;

double seconds(time::TaiNs a, time::TaiNs b) {
  return static_cast<double>(a - b) * 1e-9;
}

/// One exposure of a segment: the forward filter's results kept for the backward pass.
struct Step {
  const PoseMeasurement* m = nullptr;
  Vec3 theta_measured = Vec3::Zero();  ///< accumulated attitude of the last solved pose
  const PoseMeasurement* attitude_reference = nullptr;  ///< that solved pose
  StateMatrix F = StateMatrix::Identity();              ///< from the previous step
  StateVector x_pred = StateVector::Zero(), x = StateVector::Zero();
  StateMatrix P_pred = StateMatrix::Zero(), P = StateMatrix::Zero();
  StateMatrix Q = StateMatrix::Zero();  ///< process covariance of the interval before
  SharedLoadings E;                     ///< filtered shared error loadings
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

/// Kalman update of `s` (predicted) with its solved pose; false when S is not positive definite.
/// `nis`: the innovation's chi-square (6 degrees of freedom under the model).
bool update(Step& s, Eigen::Index shared_cols, double& nis) {
  const PoseMeasurement& m = *s.m;
  Mat6 S_inv;
  const Mat6 S = s.P_pred.topLeftCorner<6, 6>() + m.cov_noise;
  if (!uncertainty::inverse_spd<6>(0.5 * (S + S.transpose()), S_inv)) return false;
  const Gain K = s.P_pred.leftCols<6>() * S_inv;
  Vec6 y;
  y << s.theta_measured, m.T_p_s.translation();
  const Vec6 innovation = y - s.x_pred.head<6>();
  // The step test's chi-square is over the innovation's whole covariance: its noise part S and
  // the change of the shared error since the prediction, (M_k - H F E_k-1) z (a mark excluded
  // or a camera lost moves the calibration error of the pose; that is no acceleration step).
  const SharedLoadings6 M = padded(m.shared, shared_cols);
  const SharedLoadings6 D = M - s.E.topRows<6>();
  const Mat6 S_full = S + D * D.transpose();
  Mat6 S_full_inv;
  nis = uncertainty::inverse_spd<6>(0.5 * (S_full + S_full.transpose()), S_full_inv)
            ? innovation.dot(S_full_inv * innovation)
            : 0.0;
  s.x = s.x_pred + K * innovation;
  StateMatrix I_KH = StateMatrix::Identity();
  I_KH.leftCols<6>() -= K;
  // Joseph form: symmetric and positive semi-definite whatever the rounding.
  s.P = I_KH * s.P_pred * I_KH.transpose() + K * m.cov_noise * K.transpose();
  s.E = I_KH * s.E + K * M;
  return true;
}

void init_first(Step& s, const SmootherConfig& c, Eigen::Index shared_cols) {
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
  s.x_pred = s.x;
  s.P_pred = s.P;
  s.E = SharedLoadings::Zero(kStateSize, shared_cols);
  s.E.topRows<6>() = padded(m.shared, shared_cols);
}

/// Predicts step k from step k - 1; `jump`: the interval holds an acceleration step.
void predict(const Step& prev, const SmootherConfig& c, bool jump, Step& s) {
  const double dt = seconds(s.m->t_ns, prev.m->t_ns);
  StateMatrix& Q = s.Q;
  StateMatrix Q_jump, F_unused;
  process_model_before(
      dt, c.aero_accel_sigma_m_s2 * c.aero_accel_sigma_m_s2 / c.flow_field_time_s,
      c.aero_angular_accel_sigma_rad_s2 * c.aero_angular_accel_sigma_rad_s2 / c.flow_field_time_s,
      s.F, Q);
  if (jump) {
    // A step of the acceleration at a uniformly distributed instant of the interval.
    process_model_before(dt, c.accel_step_m_s2 * c.accel_step_m_s2 / dt,
                         c.angular_accel_step_rad_s2 * c.angular_accel_step_rad_s2 / dt, F_unused,
                         Q_jump);
    Q += Q_jump;
  }
  s.x_pred = s.F * prev.x;
  s.P_pred = s.F * prev.P * s.F.transpose() + Q;
  s.E = s.F * prev.E;
  s.x = s.x_pred;
  s.P = s.P_pred;
  s.theta_measured = prev.theta_measured;
  s.attitude_reference = prev.attitude_reference;
}

/// Forward filter over one segment (first and last exposures solved), with acceleration steps
/// in the intervals ending at the exposures marked in `jump`. `alarm`: the first exposure whose
/// innovation chi-square exceeds `nis_limit` and whose interval holds no step yet, else -1.
std::vector<Step> filter(std::span<const PoseMeasurement> seg, const SmootherConfig& c,
                         Eigen::Index shared_cols, const std::vector<char>& jump, double nis_limit,
                         int& alarm, SmootherCounters& counters) {
  std::vector<Step> steps(seg.size());
  steps[0].m = &seg[0];
  steps[0].attitude_reference = &seg[0];
  init_first(steps[0], c, shared_cols);
  alarm = -1;
  for (std::size_t k = 1; k < seg.size(); ++k) {
    Step& s = steps[k];
    s.m = &seg[k];
    predict(steps[k - 1], c, jump[k] != 0, s);
    if (!s.m->solved) continue;
    // The attitude accumulates the solved poses' increments (left, pylon frame).
    s.theta_measured += geometry::rotvec_from_rotation(
        s.m->T_p_s.linear() * steps[k - 1].attitude_reference->T_p_s.linear().transpose());
    s.attitude_reference = s.m;
    double nis = 0;
    if (!update(s, shared_cols, nis))
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
                                    SmootherCounters& counters) {
  const double nis_limit = uncertainty::chi_square_quantile(
      uncertainty::Probability(1 - c.step_false_alarm), uncertainty::DegreesOfFreedom(6));
  jump.assign(seg.size(), 0);
  int alarm = -1;
  std::vector<Step> steps = filter(seg, c, shared_cols, jump, nis_limit, alarm, counters);
  for (int rerun = 0; alarm > 0 && rerun < 64; ++rerun) {
    jump[static_cast<std::size_t>(alarm)] = 1;
    if (alarm > 1) jump[static_cast<std::size_t>(alarm - 1)] = 1;
    steps = filter(seg, c, shared_cols, jump, nis_limit, alarm, counters);
  }
  for (std::size_t k = 0; k < seg.size(); ++k) {
    counters.steps += jump[k] ? 1 : 0;
    if (k > 0 && !seg[k].solved) ++counters.predicted;
    if (seg[k].solved) ++counters.measurements;
  }
  return steps;
}

SmoothedState to_output(const Step& s, const StateVector& x, const StateMatrix& P,
                        const SharedLoadings& E, int segment) {
  SmoothedState out;
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
  out.shared = E;
  if (s.m->solved) out.cov_noise_per_exposure = s.m->cov_noise;
  return out;
}

/// Backward (RTS) pass; appends the segment's smoothed states.
void smooth_back(std::vector<Step>& steps, const std::vector<char>& jump, int segment,
                 std::vector<SmoothedState>& out, SmootherCounters& counters) {
  const std::size_t n = steps.size();
  std::vector<SmoothedState> seg(n);
  StateVector x_next = steps[n - 1].x;
  StateMatrix P_next = steps[n - 1].P;
  SharedLoadings E_next = steps[n - 1].E;
  seg[n - 1] = to_output(steps[n - 1], x_next, P_next, E_next, segment);
  for (std::size_t k = n - 1; k-- > 0;) {
    const Step& s = steps[k];
    const Step& after = steps[k + 1];
    StateMatrix P_pred_inv;
    if (!inverse_scaled(after.P_pred, P_pred_inv)) {
      ++counters.update_failures;
      P_pred_inv.setZero();  // no smoothing gain: the filtered estimate
    }
    const StateMatrix C = s.P * after.F.transpose() * P_pred_inv;
    const StateVector x = s.x + C * (x_next - after.x_pred);
    // P + C (P_next - P_pred) C^T, written as a sum of positive semi-definite terms (equal for
    // the exact gain, P_pred = F P F^T + Q): rounding in C cannot make it indefinite.
    StateMatrix I_CF = StateMatrix::Identity() - C * after.F;
    const StateMatrix P = I_CF * s.P * I_CF.transpose() + C * (after.Q + P_next) * C.transpose();
    // The shared error of the predicted state is F E (steps[k+1].E before its update).
    SharedLoadings E = s.E + C * (E_next - after.F * s.E);
    seg[k] = to_output(s, x, P, E, segment);
    x_next = x;
    P_next = P;
    E_next = std::move(E);
  }
  for (std::size_t k = 0; k < n; ++k)
    seg[k].step = jump[k] != 0;
  out.insert(out.end(), seg.begin(), seg.end());
}

void process_model_before(double dt, double jerk_psd, double angular_jerk_psd, StateMatrix& F,
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

std::vector<SmoothedState> smooth_trajectory_before(std::span<const PoseMeasurement> measurements,
                                                    const SmootherConfig& config,
                                                    SmootherCounters* counters) {
  SmootherCounters local;
  SmootherCounters& c = counters ? *counters : local;
  Eigen::Index shared_cols = 0;
  for (const PoseMeasurement& m : measurements)
    if (m.solved) shared_cols = std::max(shared_cols, m.shared.cols());
  std::vector<SmoothedState> out;
  const std::size_t n = measurements.size();
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
    std::vector<char> jump;
    std::vector<Step> steps =
        filter_with_steps(measurements.subspan(k, last - k + 1), config, shared_cols, jump, c);
    smooth_back(steps, jump, segment++, out, c);
    ++c.segments;
    k = last + 1;
  }
  return out;
}

}  // namespace
}  // namespace before_issue26_memory

namespace {

constexpr int kExposures = 160;  // 0.4 s at 400 fps: captive, the stroke, free flight

std::vector<PoseMeasurement> main_job_like_measurements() {
  const sim::Scenario scenario = sim::load_scenario(test::scenario_path("store_separation"));
  const sim::Simulator sim(scenario, 2626);
  pipeline::ExposureProcessor proc(sim.calibrated_rig(), sim.pylon_survey(), sim.store_survey(),
                                   pipeline::ProcessorConfig{});
  std::vector<PoseMeasurement> out;
  for (int k = 0; k < std::min(kExposures, sim.num_exposures()); ++k) {
    const test::SimExposure in = test::make_exposure(sim, k);
    out.push_back(measurement_from(proc.process(in.exposure, in.ids)));
  }
  // A 10 ms gap the smoother predicts through, and a 30 ms gap (over max_gap_s) ending the
  // first segment.
  for (int k = 90; k < 94; ++k)
    out[static_cast<std::size_t>(k)].solved = false;
  for (int k = 120; k < 132; ++k)
    out[static_cast<std::size_t>(k)].solved = false;
  return out;
}

// The largest relative difference seen (0: bit-identical), printed for docs/performance.md.
double largest_relative_difference = 0;

template <typename A, typename B>
void expect_close(const A& now, const B& before, const char* what, std::size_t k) {
  const double relative = (now - before).norm() / std::max(before.norm(), 1e-300);
  largest_relative_difference = std::max(largest_relative_difference, relative);
  EXPECT_LE(relative, 1e-12) << what << " at state " << k;
}

TEST(SmootherReference, SameStatesCovariancesAndSharedLoadingsAsBeforeTheMemoryReduction) {
  const std::vector<PoseMeasurement> in = main_job_like_measurements();
  SmootherCounters c_now, c_before;
  const std::vector<SmoothedState> now = smooth_trajectory(in, SmootherConfig{}, &c_now);
  const std::vector<SmoothedState> before =
      before_issue26_memory::smooth_trajectory_before(in, SmootherConfig{}, &c_before);
  std::printf("%zu states, %llu segments, %llu predicted, %llu step intervals\n", now.size(),
              static_cast<unsigned long long>(c_now.segments),
              static_cast<unsigned long long>(c_now.predicted),
              static_cast<unsigned long long>(c_now.steps));
  // The input exercises what it should: steps (the re-run filter), a gap, two segments.
  EXPECT_GT(c_before.steps, 0u);
  EXPECT_GT(c_before.predicted, 0u);
  EXPECT_EQ(c_before.segments, 2u);
  EXPECT_EQ(c_now.segments, c_before.segments);
  EXPECT_EQ(c_now.measurements, c_before.measurements);
  EXPECT_EQ(c_now.predicted, c_before.predicted);
  EXPECT_EQ(c_now.left_out, c_before.left_out);
  EXPECT_EQ(c_now.update_failures, c_before.update_failures);
  EXPECT_EQ(c_now.steps, c_before.steps);
  ASSERT_EQ(now.size(), before.size());
  for (std::size_t k = 0; k < now.size(); ++k) {
    const SmoothedState& a = now[k];
    const SmoothedState& b = before[k];
    EXPECT_EQ(a.t_ns, b.t_ns);
    EXPECT_EQ(a.segment, b.segment);
    EXPECT_EQ(a.measured, b.measured);
    EXPECT_EQ(a.step, b.step);
    expect_close(a.T_p_s.matrix(), b.T_p_s.matrix(), "T_p_s", k);
    expect_close(a.angular_rate_p, b.angular_rate_p, "angular rate", k);
    expect_close(a.velocity_p, b.velocity_p, "velocity", k);
    expect_close(a.angular_accel_p, b.angular_accel_p, "angular acceleration", k);
    expect_close(a.accel_p, b.accel_p, "acceleration", k);
    expect_close(a.cov_noise, b.cov_noise, "noise covariance", k);
    ASSERT_EQ(a.shared.cols(), b.shared.cols());
    expect_close(a.shared, b.shared, "shared loadings", k);
    expect_close(a.cov_noise_per_exposure, b.cov_noise_per_exposure, "per-exposure noise", k);
  }
  std::printf("largest relative difference: %.3g\n", largest_relative_difference);
}

}  // namespace
}  // namespace storetrack::smooth
