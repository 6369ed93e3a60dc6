#include "storetrack/pipeline/exposure_processor.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <span>
#include <stdexcept>
#include <utility>

#include <Eigen/Eigenvalues>

#include "sample_fields.hpp"
#include "storetrack/match/mark_estimator.hpp"
#include "storetrack/pose/body_pose.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::pipeline {

using geometry::Mat3;
using geometry::Mat6;
using geometry::Transform;
using geometry::Vec2;
using geometry::Vec3;
using geometry::Vec6;
using uncertainty::Source;

namespace {

/// True when the largest rotation standard uncertainty implied by a body fit's normal matrix
/// (J^T W J over left perturbations (r, t); its inverse from the fit, which fails unless it is
/// positive definite) is finite and at most max_rotation_sigma_rad.
bool pose_well_determined(const geometry::Mat6& normal_matrix_inverse,
                          double max_rotation_sigma_rad) {
  if (!normal_matrix_inverse.allFinite()) return false;
  // Closed-form 3x3 eigenvalues: this runs for every body of every exposure.
  Eigen::SelfAdjointEigenSolver<geometry::Mat3> es;
  es.computeDirect(normal_matrix_inverse.topLeftCorner<3, 3>(), Eigen::EigenvaluesOnly);
  const double largest = es.eigenvalues().maxCoeff();
  return largest >= 0 && std::sqrt(largest) <= max_rotation_sigma_rad;
}

constexpr int kCentroid = uncertainty::index(Source::kCentroid);
constexpr int kIntrinsic = uncertainty::index(Source::kIntrinsic);
constexpr int kExtrinsic = uncertainty::index(Source::kExtrinsic);
constexpr int kSync = uncertainty::index(Source::kSync);
constexpr int kSurvey = uncertainty::index(Source::kSurvey);

using uncertainty::Loadings6;

// A body's fitted pose with its error model: xi = sum over marks, loadings on common factors,
// independent (centroid, survey) covariances.
struct BodySolution {
  bool valid = false;
  Transform T_w_b = Transform::Identity();
  Loadings6 loadings;
  Mat6 cov_centroid = Mat6::Zero();
  Mat6 cov_survey = Mat6::Zero();
  Loadings6 survey_loadings;  ///< whitened, 3 columns per surveyed mark (PoseResult)
  int marks_used = 0;
  double chi2 = 0;
};

// The result slot of the next mark: the element left by an earlier exposure when there is one
// (its observations and loadings keep their storage), the fields not always written reset.
MarkResult& next_mark(std::vector<MarkResult>& marks, size_t index) {
  if (index == marks.size()) marks.emplace_back();
  MarkResult& m = marks[index];
  m.excluded = false;
  m.cov_w.setZero();
  m.cov_by_source = zero_by_source<Mat3>();
  return m;
}

// Takes the solution's loadings (moved: the relative pose is derived from the body solutions
// before they are handed over).
void fill_pose(BodySolution&& b, const uncertainty::CalibrationFactors& f, PoseResult& out) {
  out.valid = b.valid;
  out.T = b.T_w_b;
  out.marks_used = b.marks_used;
  out.chi2 = b.chi2;
  // Monte Carlo draws solve without uncertainty: no loadings, covariances stay zero.
  if (!b.valid || b.loadings.cols() != f.num_factors()) return;
  out.cov_by_source[kCentroid] = b.cov_centroid;
  out.cov_by_source[kIntrinsic] = uncertainty::covariance_of(b.loadings, f, Source::kIntrinsic);
  out.cov_by_source[kExtrinsic] = uncertainty::covariance_of(b.loadings, f, Source::kExtrinsic);
  out.cov_by_source[kSync] = uncertainty::covariance_of(b.loadings, f, Source::kSync);
  out.cov_by_source[kSurvey] = b.cov_survey;
  out.cov = Mat6::Zero();
  for (const Mat6& c : out.cov_by_source)
    out.cov += c;
  out.loadings = std::move(b.loadings);
  out.survey_loadings = std::move(b.survey_loadings);
}

/// One observation of a surveyed mark for a single-view resection.
struct ResectionView {
  const camera::CalibratedCamera* camera = nullptr;
  int slot = -1;  ///< rig slot (its calibration factors)
  int mark = -1;  ///< index of its mark in the resection (views of one mark share its survey error)
  Vec2 pixel_px = Vec2::Zero();
  double sigma_px = 0;
  Vec3 p_b = Vec3::Zero();
  double survey_sigma_m = 0;
  int survey_column = -1;  ///< first of its mark's 3 columns in BodySolution::survey_loadings
  /// Weight (sigma^2 I + calibration pixel covariance)^-1: the calibration's pixel errors exceed
  /// the centroid noise, and its chi-square tests the marks against both.
  geometry::Mat2 W = geometry::Mat2::Identity();
};
struct ResectionLimits {
  int min_marks = 4;
  double max_rotation_sigma_rad = 0;
  double false_alarm_probability = 0;  ///< of the reprojection chi-square test; 0: no test
};

/// Reprojection normal equations of a body pose T_w_b: Info = sum H^T W H, g = sum H^T W r,
/// chi2 = sum r^T W r (r = pixel - projection).
bool resection_normal_equations(std::span<const ResectionView> views, const Transform& T_w_b,
                                Mat6& info, Vec6& g, double& chi2) {
  info.setZero();
  g.setZero();
  chi2 = 0;
  for (const ResectionView& v : views) {
    Eigen::Matrix<double, 2, 6> H;
    const auto px = camera::project_body_point(*v.camera, T_w_b, v.p_b, &H);
    if (!px) return false;
    const Vec2 r = v.pixel_px - *px;
    const Eigen::Matrix<double, 6, 2> HtW = H.transpose() * v.W;
    info.noalias() += HtW * H;
    g.noalias() += HtW * r;
    chi2 += r.dot(v.W * r);
  }
  return true;
}

/// Pose of a body from its marks' pixels (resection, Gauss-Newton on the reprojection error
/// from `T_w_b`, weights W_i), for marks seen by one camera each where no triangulation is
/// possible. GUM propagation of the estimator (pose error = sum K_i e_i, K_i = Info^-1 H_i^T
/// W_i): centroid sum K_i sigma_i^2 K_i^T, the calibration through the cameras' loadings (one
/// camera's error moves all its views alike), the survey per mark. The sync term is not modelled
/// (no velocity). The chi-square (dof 2 views - 6) treats the calibration pixel errors as
/// independent between views; a camera's common part is largely absorbed by the pose.
bool resect_body(std::span<ResectionView> views, Transform T_w_b,
                 const uncertainty::CalibrationFactors& factors, const ResectionLimits& limits,
                 bool with_uncertainty, int survey_columns, BodySolution& sol) {
  const int marks = views.empty() ? 0 : views.back().mark + 1;
  if (marks < limits.min_marks) return false;
  for (ResectionView& v : views) {
    camera::ProjectionJacobians J;
    if (!camera::project_body_point(*v.camera, T_w_b, v.p_b, nullptr, &J)) return false;
    const geometry::Mat2 S = v.sigma_px * v.sigma_px * geometry::Mat2::Identity() +
                             uncertainty::pixel_covariance(factors, v.slot, J);
    if (!uncertainty::inverse_spd<2>(S, v.W)) return false;
  }
  Mat6 info;
  Vec6 g;
  double chi2 = 0;
  bool converged = false;
  for (int iter = 0; iter < 12 && !converged; ++iter) {
    if (!resection_normal_equations(views, T_w_b, info, g, chi2)) return false;
    Vec6 step;
    if (!uncertainty::solve_spd<6>(info, g, step)) return false;
    T_w_b = geometry::perturb_left(T_w_b, step);
    converged = step.norm() < 1e-9;  // rad and m: far below any mark's sigma
  }
  Mat6 cov;
  if (!converged || !resection_normal_equations(views, T_w_b, info, g, chi2) ||
      !uncertainty::inverse_spd<6>(info, cov) ||
      !pose_well_determined(cov, limits.max_rotation_sigma_rad))
    return false;
  const int dof = 2 * static_cast<int>(views.size()) - 6;
  if (limits.false_alarm_probability > 0 &&
      chi2 > uncertainty::chi_square_quantile(
                 uncertainty::Probability(1 - limits.false_alarm_probability),
                 uncertainty::DegreesOfFreedom(dof)))
    return false;
  sol = BodySolution{};
  sol.valid = true;
  sol.T_w_b = T_w_b;
  sol.marks_used = marks;
  sol.chi2 = chi2;
  if (!with_uncertainty) return true;
  sol.loadings = Loadings6::Zero(6, factors.num_factors());
  sol.survey_loadings = Loadings6::Zero(6, survey_columns);
  Eigen::Matrix<double, 6, 3> survey_gain = Eigen::Matrix<double, 6, 3>::Zero();
  for (size_t i = 0; i < views.size(); ++i) {
    const ResectionView& v = views[i];
    camera::ProjectionJacobians J;
    Eigen::Matrix<double, 2, 6> H;
    camera::project_body_point(*v.camera, T_w_b, v.p_b, &H, &J);
    const Eigen::Matrix<double, 6, 2> K = cov * H.transpose() * v.W;
    sol.cov_centroid.noalias() += v.sigma_px * v.sigma_px * K * K.transpose();
    // A calibration error d theta shifts the pixel by J d theta: the pose by -K J d theta.
    const auto& cf = factors.camera(v.slot);
    if (cf.intrinsic.cols() > 0)
      sol.loadings.middleCols(cf.intrinsic_begin, cf.intrinsic.cols()).noalias() -=
          K * (J.d_intrinsics * cf.intrinsic);
    if (cf.extrinsic.cols() > 0)
      sol.loadings.middleCols(cf.extrinsic_begin, cf.extrinsic.cols()).noalias() -=
          K * (J.d_pose * cf.extrinsic);
    // A survey error d q of the mark moves its pixel by d pixel / d p_w R d q in every view.
    survey_gain.noalias() += K * J.d_point_world * T_w_b.linear();
    if (i + 1 == views.size() || views[i + 1].mark != v.mark) {
      sol.cov_survey.noalias() +=
          v.survey_sigma_m * v.survey_sigma_m * survey_gain * survey_gain.transpose();
      sol.survey_loadings.middleCols<3>(v.survey_column) = v.survey_sigma_m * survey_gain;
      survey_gain.setZero();
    }
  }
  return true;
}

double wrap_angle(double a) {
  return std::remainder(a, 2.0 * M_PI);
}

}  // namespace

const MarkResult* ExposureResult::find_mark(int id) const {
  for (const MarkResult& m : marks)
    if (m.id == id) return &m;
  return nullptr;
}

struct ExposureProcessor::Prepared {
  time::TaiNs t_ref_tai_ns = std::numeric_limits<time::TaiNs>::min();
  struct Obs {
    int slot = -1;
    int camera_id = -1;
    int mark_index = -1;
    Vec2 pixel_px = Vec2::Zero();
    double sigma_px = 0;
    geometry::Mat2 information_px = geometry::Mat2::Identity();  ///< the matcher's weight
  };
  struct Mark {
    int id = -1;
    char body = '?';
    std::vector<Obs> obs;  ///< camera order: the estimate's views
    Vec3 velocity_w = Vec3::Zero();
    bool velocity_valid = false;
    bool motion_corrected = false;
    const triangulate::Result* estimate = nullptr;  ///< the matcher's (>= 2 views)
  };
  std::vector<Mark> marks;
  std::vector<double> dt_s;  ///< per rig slot: camera mid-time - reference time
  /// Per rig slot: a Monte Carlo draw's error of that camera's time offset (0 nominal).
  std::vector<double> sync_error_s;
  /// Per rig slot: the standard uncertainty of that camera's exposure time this exposure, as its
  /// unit stated it (exposure_time_sigma_ns; its clock, shared with the unit's other cameras).
  std::vector<double> clock_sigma_s;
  std::vector<bool> slot_used;
  int cameras_used = 0;
  bool clock_not_locked = false;
  /// Start of the single-view resection per body (0 pylon, 1 store): the matcher's pose of this
  /// exposure or the body's last solved one, from its motion state (see resect()).
  std::array<std::optional<Transform>, 2> initial_T_w_b;
};

struct ExposureProcessor::Exclusions {
  std::vector<int> ids;
  std::map<int, Mat3> weights;  ///< pose-fit weights (covariances) per mark id
  bool contains(int id) const { return std::find(ids.begin(), ids.end(), id) != ids.end(); }
};

struct ExposureProcessor::Scratch {
  Prepared prepared;
  std::vector<size_t> body_marks, fit_marks;
  std::vector<rigid::MarkEstimate> estimates;
  std::vector<Vec3> q_body, p_world;
  std::vector<Mat3> cov_world;
  std::vector<double> survey_sigma;
  std::vector<int> survey_column;
  pose::BodyFit fit;
};

ExposureProcessor::ScratchBuffer::ScratchBuffer() : scratch(std::make_unique<Scratch>()) {}
ExposureProcessor::ScratchBuffer::ScratchBuffer(const ScratchBuffer&)
    : scratch(std::make_unique<Scratch>()) {}
ExposureProcessor::ScratchBuffer& ExposureProcessor::ScratchBuffer::operator=(
    const ScratchBuffer&) {
  return *this;  // scratch only: nothing to copy
}
ExposureProcessor::ScratchBuffer::ScratchBuffer(ScratchBuffer&&) noexcept = default;
ExposureProcessor::ScratchBuffer& ExposureProcessor::ScratchBuffer::operator=(
    ScratchBuffer&&) noexcept = default;
ExposureProcessor::ScratchBuffer::~ScratchBuffer() = default;

ExposureProcessor::ExposureProcessor(const camera::RigCalibration& rig,
                                     const survey::RigidBodySurvey& pylon,
                                     const survey::RigidBodySurvey& store,
                                     const ProcessorConfig& config)
    : rig_(rig),
      pylon_(pylon),
      store_(store),
      config_(config),
      factors_(rig),
      matcher_(rig, {pylon, store}, config.matcher),
      tracker_(factors_, config.pose_tracker) {
  if (rig_.cameras.empty()) throw std::invalid_argument("ExposureProcessor: empty rig");
  if (config_.min_cameras_per_mark < 2)
    throw std::invalid_argument("ExposureProcessor: min_cameras_per_mark must be >= 2");
  if (config_.min_pose_marks < 3)
    throw std::invalid_argument("ExposureProcessor: min_pose_marks must be >= 3");
  if (!(config_.coverage_factor > 0))
    throw std::invalid_argument("ExposureProcessor: coverage_factor must be > 0");
  if (config_.max_mark_id < 0 || config_.max_mark_id > 65535)
    throw std::invalid_argument("ExposureProcessor: max_mark_id must be in 0..65535");
  for (size_t s = 0; s < rig_.cameras.size(); ++s) {
    const int id = rig_.cameras[s].camera_id;
    if (id < 0 || id > 255) throw std::invalid_argument("ExposureProcessor: camera_id not 0..255");
    if (slot_of_camera_id_.size() <= static_cast<size_t>(id))
      slot_of_camera_id_.resize(static_cast<size_t>(id) + 1, -1);
    if (slot_of_camera_id_[static_cast<size_t>(id)] >= 0)
      throw std::invalid_argument("ExposureProcessor: duplicate camera_id in the rig");
    slot_of_camera_id_[static_cast<size_t>(id)] = static_cast<int>(s);
  }
  for (const auto* survey : {&pylon_, &store_})
    for (const survey::SurveyedMark& m : survey->marks)
      if (m.id < 0 || m.id > config_.max_mark_id || !(m.sigma_m >= 0))
        throw std::invalid_argument("ExposureProcessor: survey '" + survey->name +
                                    "' has a mark id out of range or a negative sigma");
}

void ExposureProcessor::reset_tracking() {
  matcher_.reset_tracking();
}

ExposureResult ExposureProcessor::process(const AlignedExposure& exposure) {
  ExposureResult out;
  matcher_.match(exposure.cameras, matched_);
  process_into_new(exposure, matched_, out);
  return out;
}

void ExposureProcessor::process(const AlignedExposure& exposure, ExposureResult& out) {
  matcher_.match(exposure.cameras, matched_);
  process(exposure, matched_, out);
}

match::MatchResult ExposureProcessor::identify(const AlignedExposure& exposure,
                                               const MarkIds& ids) {
  if (ids.size() != exposure.cameras.size())
    throw std::invalid_argument("ExposureProcessor: ids must have one entry per camera");
  MarkIds usable = ids;
  for (std::vector<int>& camera : usable)
    for (int& id : camera)
      if (id > config_.max_mark_id) {
        ++counters_.id_out_of_range;
        id = -1;
      }
  return matcher_.estimate_identified(exposure.cameras, usable);
}

ExposureResult ExposureProcessor::process(const AlignedExposure& exposure, const MarkIds& ids) {
  return process(exposure, identify(exposure, ids));
}

void ExposureProcessor::prepare(const AlignedExposure& exposure, const match::MatchResult& marks,
                                ProcessorCounters& counters, Prepared& prep) const {
  // Every field is set below; the vectors keep their storage (a mark's views too, while the
  // number of marks does not shrink).
  prep.t_ref_tai_ns = std::numeric_limits<time::TaiNs>::min();
  prep.cameras_used = 0;
  prep.clock_not_locked = false;
  prep.dt_s.assign(rig_.cameras.size(), 0.0);
  prep.sync_error_s.assign(rig_.cameras.size(), 0.0);
  prep.clock_sigma_s.assign(rig_.cameras.size(), 0.0);
  prep.slot_used.assign(rig_.cameras.size(), false);
  if (marks.has_reference_time) prep.t_ref_tai_ns = marks.reference_mid_tai_ns;
  for (const msg::MarkObservations& obs : exposure.cameras) {
    const size_t cid = obs.camera_id;
    const int slot = cid < slot_of_camera_id_.size() ? slot_of_camera_id_[cid] : -1;
    if (slot < 0 || prep.slot_used[static_cast<size_t>(slot)]) {
      ++counters.unknown_camera;  // unknown or delivered twice: the aligner should not do that
      continue;
    }
    prep.slot_used[static_cast<size_t>(slot)] = true;
    // Unknown (an older message's figure is refused at decoding; a unit that does not know
    // its clock's sigma): counted; the calibration's offset sigma alone then stands.
    if (obs.exposure_time_sigma_ns == msg::mark_observations_invalid::kExposureTimeSigmaNs)
      ++counters.time_sigma_unknown;
    else
      prep.clock_sigma_s[static_cast<size_t>(slot)] = obs.exposure_time_sigma_ns * 1e-9;
    if (obs.clock_state != static_cast<std::uint8_t>(time::ClockState::kLocked))
      prep.clock_not_locked = true;
  }
  std::vector<bool> contributed(rig_.cameras.size(), false);
  prep.marks.resize(marks.marks.size());
  for (size_t i = 0; i < marks.marks.size(); ++i) {
    const match::MatchedMark& mm = marks.marks[i];
    Prepared::Mark& m = prep.marks[i];
    m.id = mm.id;
    m.body = mm.body == kPylonBody ? 'p' : mm.body == kStoreBody ? 's' : '?';
    m.velocity_w = mm.velocity_w;
    m.velocity_valid = mm.velocity_valid;
    m.motion_corrected = mm.motion_corrected;
    m.estimate = mm.triangulated ? &mm.estimate : nullptr;
    m.obs.clear();
    for (const match::MatchedObservation& mo : mm.observations) {
      const int slot = slot_of_camera_id_[static_cast<size_t>(mo.camera_id)];
      m.obs.push_back(
          {slot, mo.camera_id, mo.mark_index, mo.raw_px, mo.sigma_px, mo.information_px});
      prep.dt_s[static_cast<size_t>(slot)] = mo.time_offset_s;
      contributed[static_cast<size_t>(slot)] = true;
    }
  }
  prep.cameras_used = static_cast<int>(std::count(contributed.begin(), contributed.end(), true));
  for (size_t b = 0; b < prep.initial_T_w_b.size(); ++b) {
    // The matcher's pose of this exposure, else the body's last solved one (if recent).
    if (b < marks.fitted.size() && marks.fitted[b])
      prep.initial_T_w_b[b] = marks.T_w_b[b];
    else
      prep.initial_T_w_b[b] =
          matcher_.motion(static_cast<int>(b))
              .recent_world_pose(prep.t_ref_tai_ns, config_.matcher.track_max_gap_s);
  }
}

void ExposureProcessor::solve(const Prepared& prep,
                              const std::vector<camera::CalibratedCamera>& cameras,
                              const survey::RigidBodySurvey& pylon_survey,
                              const survey::RigidBodySurvey& store_survey, bool with_uncertainty,
                              const Exclusions* fixed_exclusions, ExposureResult& out,
                              ProcessorCounters& counters, Scratch& scratch) const {
  const int nz = factors_.num_factors();
  // Survey loadings: 3 columns per surveyed mark, the pylon's marks first, then the store's.
  const int survey_columns =
      3 * static_cast<int>(pylon_survey.marks.size() + store_survey.marks.size());
  auto survey_column = [&](char body, const survey::SurveyedMark* s) {
    const survey::RigidBodySurvey& sv = body == 'p' ? pylon_survey : store_survey;
    const auto first = body == 'p' ? 0 : pylon_survey.marks.size();
    return 3 * static_cast<int>(first + static_cast<size_t>(s - sv.marks.data()));
  };
  size_t marks_used = 0;
  out.marks.reserve(prep.marks.size());
  std::vector<triangulate::Observation> tri_obs;
  triangulate::Result drawn;
  for (const Prepared::Mark& mark : prep.marks) {
    if (static_cast<int>(mark.obs.size()) < config_.min_cameras_per_mark) {
      ++counters.too_few_cameras;
      continue;
    }
    if (mark.estimate == nullptr) continue;  // the matcher could not triangulate it (counted)
    // The nominal solution is the matcher's estimate; a Monte Carlo draw repeats the same
    // estimator (weights, motion correction, start) on its drawn pixels and calibration.
    const triangulate::Result* estimate = mark.estimate;
    if (fixed_exclusions != nullptr) {
      tri_obs.clear();
      for (const Prepared::Obs& o : mark.obs) {
        // The estimator corrects by velocity * stated offset (when motion_corrected); the mark
        // really moved by velocity * (offset + its error).
        const auto slot = static_cast<size_t>(o.slot);
        const double offset_s =
            (mark.motion_corrected ? prep.dt_s[slot] : 0.0) + prep.sync_error_s[slot];
        tri_obs.push_back(
            match::estimator_view(cameras[slot], o.pixel_px, o.sigma_px, o.information_px,
                                  mark.velocity_valid ? &mark.velocity_w : nullptr, offset_s));
      }
      triangulate::Options options = match::estimator_options(mark.estimate->p_w);
      options.calibration_jacobians = false;
      if (!triangulate::triangulate(tri_obs, options, drawn)) {
        ++counters.triangulation_failed;
        continue;
      }
      estimate = &drawn;
    }
    const triangulate::Result& tri = *estimate;
    const Vec3 velocity_w = mark.velocity_w;
    const bool velocity_valid = mark.velocity_valid;
    MarkResult& m = next_mark(out.marks, marks_used);
    m.id = mark.id;
    m.body = mark.body;
    m.p_w = tri.p_w;
    m.velocity_w = velocity_w;
    m.velocity_valid = velocity_valid;
    m.motion_corrected = mark.motion_corrected;
    m.chi2 = tri.chi2;
    m.observations.resize(mark.obs.size());
    for (size_t i = 0; i < mark.obs.size(); ++i) {
      m.observations[i].camera_id = mark.obs[i].camera_id;
      m.observations[i].mark_index = mark.obs[i].mark_index;
      m.observations[i].residual_px = tri.residual_px[i];
      m.observations[i].sigma_px = mark.obs[i].sigma_px;
      m.observations[i].information_px = mark.obs[i].information_px;
    }
    if (with_uncertainty) {
      // dp/dtheta = -K_i dproj_i/dtheta for the parameters of observation i's camera (each
      // camera observes a mark once); loadings = dp/dtheta * F (whitened factors). Uncoupled
      // factors (version-1 calibration): each camera owns its columns, so a mark loads only on
      // the factors of the cameras that saw it and each source's covariance is the sum of the
      // per-camera blocks' B B^T. Coupled (joint covariance): cameras share columns, the
      // blocks add up in the loadings and each source's covariance is L_s L_s^T.
      m.loadings.setZero(3, nz);
      Mat3 cov_intrinsic = Mat3::Zero(), cov_extrinsic = Mat3::Zero();
      const bool coupled = factors_.coupled();
      for (size_t i = 0; i < mark.obs.size(); ++i) {
        const auto& cf = factors_.camera(mark.obs[i].slot);
        const auto& K = tri.gain[i];
        const auto& J = tri.jacobians[i];
        uncertainty::add_observation_loadings(factors_, mark.obs[i].slot, K, J, m.loadings,
                                              cov_intrinsic, cov_extrinsic);
        if (velocity_valid) {
          const Vec3 moved = -K * (J.d_point_world * velocity_w);  // per second of time error
          if (cf.sync_column >= 0) m.loadings.col(cf.sync_column) = moved * cf.sync_sigma_s;
          // One clock per unit: its cameras' errors add up in one column.
          const double clock_sigma_s = prep.clock_sigma_s[static_cast<size_t>(mark.obs[i].slot)];
          if (cf.clock_column >= 0) m.loadings.col(cf.clock_column) += moved * clock_sigma_s;
        }
      }
      const Mat3 cov_sync = uncertainty::covariance_of(m.loadings, factors_, Source::kSync);
      if (coupled) {
        cov_intrinsic = uncertainty::covariance_of(m.loadings, factors_, Source::kIntrinsic);
        cov_extrinsic = uncertainty::covariance_of(m.loadings, factors_, Source::kExtrinsic);
      }
      m.cov_by_source[kCentroid] = tri.cov_centroid;
      m.cov_by_source[kIntrinsic] = cov_intrinsic;
      m.cov_by_source[kExtrinsic] = cov_extrinsic;
      m.cov_by_source[kSync] = cov_sync;
      m.cov_by_source[kSurvey].setZero();
      // The sources partition the factor columns: L L^T is the sum of the per-source parts.
      m.cov_w = tri.cov_centroid + cov_intrinsic + cov_extrinsic + cov_sync;
    } else {
      m.loadings.resize(3, 0);
    }
    ++marks_used;
  }
  out.marks.resize(marks_used);

  // Rigid-body checks (with uncertainty) or the given exclusions (Monte Carlo draws).
  auto body_marks = [&](char body) -> const std::vector<size_t>& {
    std::vector<size_t>& idx = scratch.body_marks;
    idx.clear();
    for (size_t i = 0; i < out.marks.size(); ++i)
      if (out.marks[i].body == body) idx.push_back(i);
    return idx;
  };
  const rigid::RigidCheckConfig rigid_config{config_.rigid_false_alarm_probability,
                                             config_.min_pose_marks, config_.rigid_pair_statistics};
  auto run_check = [&](char body, rigid::RigidCheckResult& check) {
    const auto& idx = body_marks(body);
    if (fixed_exclusions != nullptr) {
      for (size_t i : idx)
        out.marks[i].excluded = fixed_exclusions->contains(out.marks[i].id);
      return;
    }
    std::vector<rigid::MarkEstimate>& est = scratch.estimates;
    est.resize(idx.size());
    for (size_t k = 0; k < idx.size(); ++k) {
      const MarkResult& m = out.marks[idx[k]];
      const survey::SurveyedMark* s = (body == 'p' ? pylon_survey : store_survey).find(m.id);
      est[k].id = m.id;
      est[k].p_body = s->p_body;
      est[k].survey_sigma_m = s->sigma_m;
      est[k].p_w = m.p_w;
      est[k].cov_independent = m.cov_by_source[kCentroid];
      est[k].loadings = &m.loadings;
    }
    rigid::check_rigid_body(est, rigid_config, check);
    for (size_t k : check.excluded)
      out.marks[idx[k]].excluded = true;
    counters.marks_excluded += check.excluded.size();
  };
  run_check('p', out.pylon_check);
  run_check('s', out.store_check);

  // Body poses.
  auto fit = [&](char body) {
    BodySolution sol;
    const survey::RigidBodySurvey& survey = body == 'p' ? pylon_survey : store_survey;
    std::vector<size_t>& idx = scratch.fit_marks;
    idx.clear();
    for (size_t i : body_marks(body))
      if (!out.marks[i].excluded) idx.push_back(i);
    if (static_cast<int>(idx.size()) < config_.min_pose_marks) return sol;
    std::vector<Vec3>& q = scratch.q_body;
    std::vector<Vec3>& p = scratch.p_world;
    std::vector<Mat3>& cov = scratch.cov_world;
    std::vector<double>& sigma = scratch.survey_sigma;
    std::vector<int>& column = scratch.survey_column;
    q.resize(idx.size());
    p.resize(idx.size());
    cov.resize(idx.size());
    sigma.resize(idx.size());
    column.resize(idx.size());
    for (size_t k = 0; k < idx.size(); ++k) {
      const MarkResult& m = out.marks[idx[k]];
      const survey::SurveyedMark* s = survey.find(m.id);
      column[k] = survey_column(body, s);
      q[k] = s->p_body;
      p[k] = m.p_w;
      // Monte Carlo draws reuse the nominal weights, so that every draw runs the same
      // estimator (the weights change efficiency, not the estimate's expectation).
      cov[k] = m.cov_w;
      if (fixed_exclusions != nullptr) {
        const auto it = fixed_exclusions->weights.find(m.id);
        if (it != fixed_exclusions->weights.end()) cov[k] = it->second;
      }
      if (!(cov[k].trace() > 0)) cov[k] = Mat3::Identity() * 1e-6;
      sigma[k] = s->sigma_m;
    }
    pose::BodyFit& bf = scratch.fit;
    if (!pose::fit_body(pose::PointsInBody{q}, pose::PointsInWorld{p}, cov, sigma, bf)) return sol;
    // First-order propagation is only honest while the pose is well determined: a nearly
    // collinear set of marks (one row of the store, three marks of the pendulum's cross) leaves
    // the rotation about their line to the survey noise, and the linearised covariance then
    // understates errors of tens of degrees. The rotation block of the fit's own covariance
    // (its normal matrix, weighted by the marks' total covariances) must stay small.
    if (!pose_well_determined(bf.normal_matrix_inverse, config_.max_pose_rotation_sigma_rad)) {
      ++counters.degenerate_geometry;
      return sol;
    }
    sol.valid = true;
    sol.T_w_b = bf.T_w_b;
    sol.marks_used = static_cast<int>(idx.size());
    sol.chi2 = bf.chi2;
    if (with_uncertainty) {
      sol.loadings = Loadings6::Zero(6, nz);
      sol.survey_loadings = Loadings6::Zero(6, survey_columns);
      for (size_t k = 0; k < idx.size(); ++k) {
        const MarkResult& m = out.marks[idx[k]];
        uncertainty::add_loadings_product(bf.d_pose_d_point[k], m.loadings, sol.loadings);
        sol.cov_centroid.noalias() +=
            bf.d_pose_d_point[k] * m.cov_by_source[kCentroid] * bf.d_pose_d_point[k].transpose();
        sol.cov_survey.noalias() +=
            sigma[k] * sigma[k] * bf.d_pose_d_survey[k] * bf.d_pose_d_survey[k].transpose();
        sol.survey_loadings.middleCols<3>(column[k]) = sigma[k] * bf.d_pose_d_survey[k];
      }
    }
    return sol;
  };
  BodySolution pylon = fit('p');
  BodySolution store = fit('s');
  out.single_view_pose = false;
  for (auto [body, sol] : {std::pair{'p', &pylon}, std::pair{'s', &store}}) {
    if (sol->valid) continue;
    const survey::RigidBodySurvey& survey = body == 'p' ? pylon_survey : store_survey;
    const auto& initial = prep.initial_T_w_b[body == 'p' ? 0 : 1];
    // Every observation of the body's marks (single views and the views of triangulated marks
    // not excluded by the rigid-body test); a resection only when some mark has one view.
    std::vector<ResectionView> views;
    bool single = false;
    int marks = 0;
    for (const Prepared::Mark& mark : prep.marks) {
      const survey::SurveyedMark* sm = survey.find(mark.id);
      const MarkResult* triangulated = out.find_mark(mark.id);
      if (mark.body != body || mark.obs.empty() || sm == nullptr ||
          (triangulated && triangulated->excluded))
        continue;
      single = single || mark.obs.size() == 1;
      for (const Prepared::Obs& o : mark.obs)
        views.push_back({&cameras[static_cast<size_t>(o.slot)], o.slot, marks, o.pixel_px,
                         o.sigma_px, sm->p_body, sm->sigma_m, survey_column(body, sm)});
      ++marks;
    }
    if (!initial || !single) continue;
    ResectionLimits limits;
    limits.min_marks = config_.min_pose_marks + 1;
    limits.max_rotation_sigma_rad = config_.max_pose_rotation_sigma_rad;
    limits.false_alarm_probability =
        fixed_exclusions == nullptr ? config_.rigid_false_alarm_probability : 0.0;
    if (resect_body(views, *initial, factors_, limits, with_uncertainty, survey_columns, *sol)) {
      out.single_view_pose = true;
      ++counters.single_view_poses;
    } else {
      ++counters.single_view_rejected;
    }
  }
  out.T_p_s = PoseResult{};
  if (pylon.valid && store.valid) {
    BodySolution rel;
    rel.valid = true;
    rel.T_w_b = pylon.T_w_b.inverse() * store.T_w_b;
    rel.marks_used = store.marks_used;
    rel.chi2 = pylon.chi2 + store.chi2;
    if (with_uncertainty) {
      Mat6 A_p, A_s;
      pose::relative_pose_jacobians(pylon.T_w_b, store.T_w_b, A_p, A_s);
      // Common calibration factors add as loadings (correlated), the rest independently.
      rel.loadings = Loadings6::Zero(6, nz);
      uncertainty::add_loadings_product(A_p, pylon.loadings, rel.loadings);
      uncertainty::add_loadings_product(A_s, store.loadings, rel.loadings);
      rel.cov_centroid =
          A_p * pylon.cov_centroid * A_p.transpose() + A_s * store.cov_centroid * A_s.transpose();
      rel.cov_survey =
          A_p * pylon.cov_survey * A_p.transpose() + A_s * store.cov_survey * A_s.transpose();
      // Each body loads only on its own marks' survey columns (the pylon's first).
      const auto pylon_columns = static_cast<Eigen::Index>(3 * pylon_survey.marks.size());
      const Eigen::Index store_columns = survey_columns - pylon_columns;
      rel.survey_loadings = Loadings6::Zero(6, survey_columns);
      uncertainty::add_loadings_product(A_p, pylon.survey_loadings.leftCols(pylon_columns),
                                        rel.survey_loadings.leftCols(pylon_columns));
      uncertainty::add_loadings_product(A_s, store.survey_loadings.rightCols(store_columns),
                                        rel.survey_loadings.rightCols(store_columns));
    }
    fill_pose(std::move(rel), factors_, out.T_p_s);
    out.xyz_ypr = xyz_ypr(out.T_p_s.T);
    if (with_uncertainty) {
      const Mat6 J = output_jacobian(out.T_p_s.T);
      out.cov_xyz_ypr = J * out.T_p_s.cov * J.transpose();
      for (int s = 0; s < uncertainty::kNumSources; ++s)
        out.cov_xyz_ypr_by_source[static_cast<size_t>(s)] =
            J * out.T_p_s.cov_by_source[static_cast<size_t>(s)] * J.transpose();
    }
  }
  fill_pose(std::move(pylon), factors_, out.T_w_p);
  fill_pose(std::move(store), factors_, out.T_w_s);
}

void ExposureProcessor::fill_sample(const AlignedExposure& exposure, const Prepared& prep,
                                    ExposureResult& out) const {
  msg::FtiSample& s = out.sample;
  s = msg::FtiSample{};
  s.store_id = config_.store_id;
  s.cameras_used = static_cast<std::uint8_t>(std::min(prep.cameras_used, 254));
  s.marks_used = static_cast<std::uint8_t>(out.T_w_s.valid ? out.T_w_s.marks_used : 0);
  s.pylon_marks_used = static_cast<std::uint8_t>(out.T_w_p.valid ? out.T_w_p.marks_used : 0);
  s.trigger_seq = exposure.trigger_seq;
  s.exposure_mid_tai_ns = prep.t_ref_tai_ns;
  s.coverage_factor = static_cast<float>(config_.coverage_factor);
  // The clearance, when a geometry is configured, is the host's (clearance::SampleClearance).
  s.clearance_m = msg::fti_sample_invalid::kClearanceM;
  s.u_clearance_m = msg::fti_sample_invalid::kUClearanceM;
  s.clearance_lower_bound_m = msg::fti_sample_invalid::kClearanceLowerBoundM;
  s.clearance_part = msg::fti_sample_invalid::kClearancePart;
  std::uint16_t status = 0;
  if (out.T_p_s.valid) {
    status |= msg::fti_status::kValid;
    if (out.single_view_pose) status |= msg::fti_status::kSingleView;
    write_pose_fields(out.xyz_ypr, out.cov_xyz_ypr, out.cov_xyz_ypr_by_source, s);
  } else if (out.extrapolated) {
    status |= msg::fti_status::kValid | msg::fti_status::kExtrapolated;
    write_pose_fields(out.xyz_ypr, out.cov_xyz_ypr, out.cov_xyz_ypr_by_source, s);
  } else {
    clear_pose_fields(s);
  }
  if (!out.pylon_check.excluded_ids.empty() || !out.store_check.excluded_ids.empty() ||
      out.pylon_check.failed || out.store_check.failed)
    status |= msg::fti_status::kRigidBodyFailed;
  if (prep.clock_not_locked) status |= msg::fti_status::kClockNotLocked;
  if (exposure.calibration_moved_mask != 0) status |= msg::fti_status::kCalibrationMoved;
  bool missing = exposure.missing_camera_mask != 0;
  for (bool used : prep.slot_used)
    missing = missing || !used;
  if (missing) status |= msg::fti_status::kCameraMissing;
  const bool fewer_marks = out.T_w_s.marks_used < static_cast<int>(store_.marks.size()) ||
                           out.T_w_p.marks_used < static_cast<int>(pylon_.marks.size());
  if (missing || fewer_marks || prep.cameras_used < static_cast<int>(rig_.cameras.size()))
    status |= msg::fti_status::kDegradedGeometry;
  s.status = status;
}

ExposureResult ExposureProcessor::process(const AlignedExposure& exposure,
                                          const match::MatchResult& marks) {
  ExposureResult out;
  process_into_new(exposure, marks, out);
  return out;
}

void ExposureProcessor::process(const AlignedExposure& exposure, const match::MatchResult& marks,
                                ExposureResult& out) {
  // Every field new but the marks' storage (solve overwrites the marks it keeps).
  std::vector<MarkResult> kept_marks = std::move(out.marks);
  out = ExposureResult{};
  out.marks = std::move(kept_marks);
  process_into_new(exposure, marks, out);
}

void ExposureProcessor::process_into_new(const AlignedExposure& exposure,
                                         const match::MatchResult& marks, ExposureResult& out) {
  ++counters_.exposures;
  Scratch& scratch = *scratch_.scratch;
  prepare(exposure, marks, counters_, scratch.prepared);
  const Prepared& prep = scratch.prepared;
  out.trigger_seq = exposure.trigger_seq;
  out.reference_mid_tai_ns = prep.t_ref_tai_ns;
  out.cameras_used = prep.cameras_used;
  solve(prep, rig_.cameras, pylon_, store_, true, nullptr, out, counters_, scratch);
  if (!out.T_p_s.valid) ++counters_.pose_failed;
  // The bodies' motion states take this exposure's solutions. An unsolved T_p_s is
  // extrapolated from the store's over a short gap, or left invalid.
  for (auto [b, pose] : {std::pair{kPylonBody, &out.T_w_p}, std::pair{kStoreBody, &out.T_w_s}})
    if (pose->valid) matcher_.motion(b).last_world = {true, prep.t_ref_tai_ns, pose->T};
  tracker_.update(out, matcher_.motion(kStoreBody));
  fill_sample(exposure, prep, out);
}

MonteCarloResult ExposureProcessor::monte_carlo(const AlignedExposure& exposure,
                                                const match::MatchResult& marks, int draws,
                                                std::uint64_t seed) const {
  if (draws < 2) throw std::invalid_argument("monte_carlo: need at least 2 draws");
  ProcessorCounters scratch;
  Scratch buffers;
  Prepared& prep = buffers.prepared;
  prepare(exposure, marks, scratch, prep);
  ExposureResult nominal;
  solve(prep, rig_.cameras, pylon_, store_, true, nullptr, nominal, scratch, buffers);

  Exclusions excl;
  for (const MarkResult& m : nominal.marks)
    if (m.excluded) excl.ids.push_back(m.id);
  for (const MarkResult& m : nominal.marks)
    excl.weights[m.id] = m.cov_w;

  MonteCarloResult mc;
  for (const MarkResult& m : nominal.marks)
    mc.mark_ids.push_back(m.id);
  const size_t nm = mc.mark_ids.size();
  std::vector<Vec3> sum(nm, Vec3::Zero());
  std::vector<Mat3> sum2(nm, Mat3::Zero());
  std::vector<int> n_mark(nm, 0);
  Vec6 s_ps = Vec6::Zero(), s_out = Vec6::Zero();
  Mat6 s2_ps = Mat6::Zero(), s2_out = Mat6::Zero();
  int n_pose = 0;

  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  const int nz = factors_.num_factors();
  for (int d = 0; d < draws; ++d) {
    Eigen::VectorXd z(nz);
    for (int i = 0; i < nz; ++i)
      z(i) = normal(rng);
    // Draw the calibration (JCGM 101, 6.4.8: multivariate Gaussian) and the time offsets.
    std::vector<camera::CalibratedCamera> cams = rig_.cameras;
    Prepared p = prep;
    for (size_t c = 0; c < cams.size(); ++c) {
      const auto& cf = factors_.camera(static_cast<int>(c));
      if (cf.intrinsic.cols() > 0) {
        const camera::IntrinsicVector v =
            camera::pack(cams[c].model.intrinsics()) +
            cf.intrinsic * z.segment(cf.intrinsic_begin, cf.intrinsic.cols());
        const camera::Intrinsics& in = cams[c].model.intrinsics();
        cams[c].model = camera::CameraModel(camera::unpack(v, in.width, in.height, in.lens_model));
      }
      if (cf.extrinsic.cols() > 0)
        cams[c].T_c_w = geometry::perturb_left(
            cams[c].T_c_w, cf.extrinsic * z.segment(cf.extrinsic_begin, cf.extrinsic.cols()));
      if (cf.sync_column >= 0) p.sync_error_s[c] = cf.sync_sigma_s * z(cf.sync_column);
      if (cf.clock_column >= 0) p.sync_error_s[c] += prep.clock_sigma_s[c] * z(cf.clock_column);
    }
    for (Prepared::Mark& m : p.marks)
      for (Prepared::Obs& o : m.obs)
        o.pixel_px += Vec2(normal(rng), normal(rng)) * o.sigma_px;
    // Survey errors: the body-frame coordinates are drawn too.
    survey::RigidBodySurvey pylon = pylon_, store = store_;
    for (auto* survey : {&pylon, &store})
      for (survey::SurveyedMark& sm : survey->marks)
        sm.p_body += Vec3(normal(rng), normal(rng), normal(rng)) * sm.sigma_m;
    ExposureResult r;
    solve(p, cams, pylon, store, false, &excl, r, scratch, buffers);
    bool ok = true;
    for (size_t k = 0; k < nm; ++k) {
      const MarkResult* m = r.find_mark(mc.mark_ids[k]);
      if (m == nullptr) {
        ok = false;
        continue;
      }
      const Vec3 e = m->p_w - nominal.marks[k].p_w;
      sum[k] += e;
      sum2[k] += e * e.transpose();
      ++n_mark[k];
    }
    if (nominal.T_p_s.valid) {
      if (r.T_p_s.valid) {
        const Vec6 xi = geometry::left_difference(r.T_p_s.T, nominal.T_p_s.T);
        Vec6 o = r.xyz_ypr - nominal.xyz_ypr;
        for (int a = 3; a < 6; ++a)
          o(a) = wrap_angle(o(a));
        s_ps += xi;
        s2_ps += xi * xi.transpose();
        s_out += o;
        s2_out += o * o.transpose();
        ++n_pose;
      } else {
        ok = false;
      }
    }
    if (ok)
      ++mc.draws;
    else
      ++mc.failed_draws;
  }
  mc.mark_cov.resize(nm);
  mc.mark_mean_offset.resize(nm);
  for (size_t k = 0; k < nm; ++k) {
    const double n = std::max(n_mark[k], 2);
    const Vec3 mean = sum[k] / n;
    mc.mark_mean_offset[k] = mean;
    mc.mark_cov[k] = (sum2[k] - n * mean * mean.transpose()) / (n - 1);
  }
  if (n_pose >= 2) {
    const Vec6 m1 = s_ps / n_pose, m2 = s_out / n_pose;
    mc.cov_T_p_s = (s2_ps - n_pose * m1 * m1.transpose()) / (n_pose - 1);
    mc.cov_xyz_ypr = (s2_out - n_pose * m2 * m2.transpose()) / (n_pose - 1);
  }
  return mc;
}

}  // namespace storetrack::pipeline
