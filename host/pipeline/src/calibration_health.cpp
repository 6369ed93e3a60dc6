#include "storetrack/pipeline/calibration_health.hpp"

#include <algorithm>
#include <stdexcept>
#include <string>

#include "storetrack/camera/camera_model.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::pipeline {

using geometry::Mat6;
using geometry::Vec2;
using geometry::Vec6;

CalibrationHealthMonitor::CalibrationHealthMonitor(const camera::RigCalibration& rig,
                                                   const survey::RigidBodySurvey& pylon,
                                                   const CalibrationHealthConfig& config)
    : cameras_(rig.cameras), pylon_(pylon), config_(config) {
  if (config_.window_exposures < 2)
    throw std::invalid_argument("calibration_health.window_exposures must be >= 2");
  if (config_.baseline_windows < 1)
    throw std::invalid_argument("calibration_health.baseline_windows must be >= 1");
  if (!(config_.false_alarm_probability > 0 && config_.false_alarm_probability < 0.5))
    throw std::invalid_argument("calibration_health.false_alarm_probability must be in (0, 0.5)");
  if (config_.min_pylon_marks < 3)
    throw std::invalid_argument("calibration_health.min_pylon_marks must be >= 3");
  for (int id : config_.camera_ids)
    if (rig.find(id) == nullptr)
      throw std::invalid_argument("calibration_health.cameras: camera " + std::to_string(id) +
                                  " is not in the rig");
  threshold_ = uncertainty::chi_square_quantile(
      uncertainty::Probability(1 - config_.false_alarm_probability),
      uncertainty::DegreesOfFreedom(6));
  const std::size_t n = cameras_.size();
  health_.resize(n);
  for (std::size_t s = 0; s < n; ++s)
    health_[s].camera_id = cameras_[s].camera_id;
  marks_.assign(n, std::vector<MarkState>(pylon_.marks.size()));
  exposures_in_phase_.assign(n, 0);
  baseline_exposures_.assign(n, 0);
  seen_.assign(n, false);
}

// The pylon marks' predictions through the calibrated cameras at the first solved pylon pose;
// its error, like the calibration's, is a constant bias the baseline absorbs.
void CalibrationHealthMonitor::set_reference(const geometry::Transform& T_w_p) {
  for (std::size_t s = 0; s < cameras_.size(); ++s)
    for (std::size_t i = 0; i < pylon_.marks.size(); ++i) {
      camera::ProjectionJacobians J;
      const auto px =
          camera::project_body_point(cameras_[s], T_w_p, pylon_.marks[i].p_body, nullptr, &J);
      MarkState& m = marks_[s][i];
      m.predicted = px.has_value();
      if (px) {
        m.pixel = *px;
        m.J = J.d_pose;
      }
    }
  have_reference_ = true;
}

// Residual sums of this exposure's pylon observations (triangulated, not excluded).
void CalibrationHealthMonitor::add_observations(const AlignedExposure& exposure,
                                                const ExposureResult& result) {
  for (const MarkResult& m : result.marks) {
    if (m.body != 'p' || m.excluded) continue;
    const survey::SurveyedMark* q = pylon_.find(m.id);
    if (q == nullptr) continue;
    const auto i = static_cast<std::size_t>(q - pylon_.marks.data());
    for (const MarkResult::ObservationResidual& o : m.observations) {
      std::size_t slot = 0;
      while (slot < cameras_.size() && cameras_[slot].camera_id != o.camera_id)
        ++slot;
      const msg::MarkObservations* obs = nullptr;
      for (const msg::MarkObservations& c : exposure.cameras)
        if (c.camera_id == o.camera_id) obs = &c;
      if (slot == cameras_.size() || obs == nullptr || o.mark_index < 0 ||
          o.mark_index >= static_cast<int>(obs->mark_count) || !(o.sigma_px > 0))
        continue;
      MarkState& ms = marks_[slot][i];
      if (!ms.predicted) continue;
      const auto& mk = obs->marks[static_cast<std::size_t>(o.mark_index)];
      // sigma_px: the matcher's, wire quantisation included.
      const double w = 1.0 / (o.sigma_px * o.sigma_px);
      const Vec2 r = Vec2(mk.x_px, mk.y_px) - ms.pixel;
      if (health_[slot].baseline_done) {
        ms.w_window += w;
        ms.wr_window += w * r;
      } else {
        ms.w_base += w;
        ms.wr_base += w * r;
      }
      seen_[slot] = true;
    }
  }
}

void CalibrationHealthMonitor::end_baseline(std::size_t slot) {
  CameraHealth& h = health_[slot];
  h.baseline_done = true;
  Mat6 A = Mat6::Zero();
  h.pylon_marks = 0;
  for (const MarkState& m : marks_[slot])
    if (m.w_base > 0) {
      ++h.pylon_marks;
      A.noalias() += m.w_base * m.J.transpose() * m.J;
    }
  Mat6 A_inv;
  const auto& ids = config_.camera_ids;
  const bool listed = ids.empty() || std::find(ids.begin(), ids.end(), h.camera_id) != ids.end();
  h.monitored =
      listed && h.pylon_marks >= config_.min_pylon_marks && uncertainty::inverse_spd<6>(A, A_inv);
}

// GLS estimate of the camera's motion from its marks' mean-residual changes, and the test.
bool CalibrationHealthMonitor::test_window(std::size_t slot) {
  CameraHealth& h = health_[slot];
  Mat6 A = Mat6::Zero();
  Vec6 g = Vec6::Zero();
  for (MarkState& m : marks_[slot]) {
    if (m.w_window > 0 && m.w_base > 0) {
      const Vec2 d = m.wr_window / m.w_window - m.wr_base / m.w_base;
      const double info = 1.0 / (1.0 / m.w_window + 1.0 / m.w_base);  // 1 / v_i
      A.noalias() += info * m.J.transpose() * m.J;
      g.noalias() += info * m.J.transpose() * d;
    }
    m.w_window = 0;
    m.wr_window.setZero();
  }
  Mat6 cov;
  if (!uncertainty::inverse_spd<6>(A, cov)) return false;
  const Vec6 xi = cov * g;
  h.last_statistic = g.dot(xi);
  ++h.windows_tested;
  if (!(h.last_statistic > threshold_)) return false;
  ++h.alarms;
  h.motion = xi;
  h.motion_cov = cov;
  if (h.moved) return false;
  h.moved = true;
  h.first_alarm_exposure = exposures_;
  return true;
}

double CalibrationHealthMonitor::noncentrality(std::size_t slot, const Vec6& xi,
                                               double fraction) const {
  if (slot >= health_.size() || !health_[slot].baseline_done) return 0;
  const double W = config_.window_exposures;
  const double n_base = baseline_exposures_[slot];
  double lambda = 0;
  for (const MarkState& m : marks_[slot])
    if (m.w_base > 0) {
      const double info = 1.0 / (1.0 / (W * m.w_base / n_base) + 1.0 / m.w_base);
      lambda += info * (m.J * xi).squaredNorm();
    }
  return fraction * fraction * lambda;
}

bool CalibrationHealthMonitor::update(const AlignedExposure& exposure,
                                      const ExposureResult& result) {
  ++exposures_;
  if (!have_reference_) {
    if (!result.T_w_p.valid) return false;
    set_reference(result.T_w_p.T);
  }
  seen_.assign(seen_.size(), false);
  add_observations(exposure, result);
  bool newly_moved = false;
  const int W = config_.window_exposures;
  for (std::size_t s = 0; s < cameras_.size(); ++s) {
    if (!seen_[s]) continue;
    CameraHealth& h = health_[s];
    const int n = ++exposures_in_phase_[s];
    if (!h.baseline_done && n == W * config_.baseline_windows) {
      baseline_exposures_[s] = n;
      end_baseline(s);
      exposures_in_phase_[s] = 0;
    } else if (h.baseline_done && n == W) {
      exposures_in_phase_[s] = 0;
      if (h.monitored) {
        newly_moved = test_window(s) || newly_moved;
      } else {
        for (MarkState& m : marks_[s]) {
          m.w_window = 0;
          m.wr_window.setZero();
        }
      }
    }
  }
  return newly_moved;
}

camera::RigCalibration corrected_rig(const camera::RigCalibration& rig, int camera_id,
                                     const Vec6& motion, const Mat6& motion_cov) {
  camera::RigCalibration out = rig;
  std::size_t slot = 0;
  while (slot < out.cameras.size() && out.cameras[slot].camera_id != camera_id)
    ++slot;
  if (slot == out.cameras.size())
    throw std::invalid_argument("corrected_rig: camera " + std::to_string(camera_id) +
                                " not in the rig");
  camera::CalibratedCamera& cam = out.cameras[slot];
  cam.T_c_w = geometry::perturb_left(cam.T_c_w, motion);
  if (out.joint_covariance.size() > 0) {
    Eigen::MatrixXd joint = out.full_joint_covariance();
    const auto e =
        static_cast<Eigen::Index>(slot) * camera::kJointBlockSize + camera::kNumIntrinsics;
    joint.block<6, 6>(e, e) += motion_cov;
    camera::set_joint_covariance(out, joint);
  } else {
    cam.extrinsic_covariance += motion_cov;
  }
  return out;
}

CalibrationHealthGuard::CalibrationHealthGuard(const camera::RigCalibration& rig,
                                               const survey::RigidBodySurvey& pylon,
                                               const CalibrationHealthConfig& config,
                                               CalibrationHealthMode mode)
    : original_(rig),
      rig_(rig),
      monitor_(rig, pylon, config),
      mode_(mode),
      alarms_seen_(rig.cameras.size(), 0),
      corrected_(rig.cameras.size(), false),
      applied_(rig.cameras.size(), Vec6::Zero()),
      applied_cov_(rig.cameras.size(), Mat6::Zero()) {}

const AlignedExposure& CalibrationHealthGuard::filter(const AlignedExposure& exposure) {
  bool any = false;
  for (const CameraHealth& h : monitor_.cameras())
    any = any || h.moved;
  if (!any) return exposure;
  filtered_ = exposure;  // the vector's capacity is reused
  const bool exclude = mode_ == CalibrationHealthMode::kExclude;
  for (msg::MarkObservations& obs : filtered_.cameras)
    for (std::size_t s = 0; s < monitor_.cameras().size(); ++s) {
      if (!monitor_.cameras()[s].moved || monitor_.cameras()[s].camera_id != obs.camera_id)
        continue;
      // Used (flag, correct) or dropped (exclude): the sample carries calibration_moved.
      if (obs.mark_count > 0) filtered_.calibration_moved_mask |= 1u << s;
      if (!exclude) continue;
      // Delivered, but not used: counted missing, so the sample says so (camera_missing).
      obs.mark_count = 0;
      filtered_.missing_camera_mask |= 1u << s;
    }
  if (exclude) ++counters_.exposures_excluding;
  return filtered_;
}

// A new full-window estimate that the applied correction does not explain.
bool CalibrationHealthGuard::correction_needed(std::size_t slot) const {
  const CameraHealth& h = monitor_.cameras()[slot];
  if (!corrected_[slot]) return true;
  Mat6 info;
  if (!uncertainty::inverse_spd<6>(Mat6(h.motion_cov + applied_cov_[slot]), info)) return false;
  const Vec6 d = h.motion - applied_[slot];
  return d.dot(info * d) > monitor_.threshold();
}

bool CalibrationHealthGuard::observe(const AlignedExposure& exposure,
                                     const ExposureResult& result) {
  monitor_.update(exposure, result);
  bool rebuild = false;
  for (std::size_t s = 0; s < monitor_.cameras().size(); ++s) {
    const CameraHealth& h = monitor_.cameras()[s];
    if (!h.moved) continue;
    // The first alarm's window is partly before the move: correct from the next ones.
    const bool new_full_window = h.alarms > alarms_seen_[s] && h.alarms > 1;
    alarms_seen_[s] = h.alarms;
    if (mode_ == CalibrationHealthMode::kCorrect && new_full_window && correction_needed(s)) {
      applied_[s] = h.motion;
      applied_cov_[s] = h.motion_cov;
      corrected_[s] = true;
      rebuild = true;
    }
  }
  // As filter() marked it before processing: the sample's status bit calibration_moved.
  flagged_ = exposure.calibration_moved_mask != 0;
  if (flagged_) ++counters_.samples_flagged;
  if (!rebuild) return false;
  rig_ = original_;
  for (std::size_t s = 0; s < corrected_.size(); ++s)
    if (corrected_[s])
      rig_ = corrected_rig(rig_, monitor_.cameras()[s].camera_id, applied_[s], applied_cov_[s]);
  ++counters_.corrections;
  return true;
}

}  // namespace storetrack::pipeline
