// World registration (docs/calibration.md, "Register"): triangulate the surveyed marks in S_r,
// fit T_r_w, propagate every source's covariance to T_r_w and to each camera's T_c_w.
#include "storetrack/calib/world_registration.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <sstream>
#include <tuple>

#include "storetrack/calib/intrinsic_calibration.hpp"  // CalibrationError
#include "storetrack/calib/point_uncertainty.hpp"
#include "storetrack/geometry/symmetric_eigen.hpp"
#include "storetrack/pose/body_pose.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::calib {
namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;
using geometry::Mat3;
using geometry::Mat6;
using geometry::Transform;
using geometry::Vec3;

constexpr int kBlock = kRegistrationBlockSize;
constexpr int kExtrinsicOffset = camera::kNumIntrinsics;

/// A triangulated mark and d(p_r)/d(calibration parameters) (3 x kBlock * cameras).
struct TriangulatedMark {
  MarkRegistration mark;
  Mat3 cov_centroid = Mat3::Zero();
  MatrixXd d_point_d_calibration;
};

std::string list_ids(const std::vector<int>& ids) {
  std::ostringstream s;
  for (size_t i = 0; i < ids.size(); ++i)
    s << (i ? ", " : "") << ids[i];
  return s.str();
}

/// Sightings grouped by mark id, after checking each camera and mark against rig and survey.
std::map<int, std::vector<const MarkSighting*>> group_sightings(
    const camera::RigCalibration& rig, const survey::RigidBodySurvey& survey,
    const std::vector<MarkSighting>& sightings, const RegistrationOptions& o) {
  std::map<int, std::vector<const MarkSighting*>> by_mark;
  std::set<std::pair<int, int>> seen;
  for (const MarkSighting& s : sightings) {
    if (rig.find(s.camera) == nullptr)
      throw CalibrationError(o.observations_origin + ": camera: camera " +
                             std::to_string(s.camera) + " (mark " + std::to_string(s.mark_id) +
                             ") is not in the rig calibration " + o.rig_origin);
    if (survey.find(s.mark_id) == nullptr)
      throw CalibrationError(o.observations_origin + ": point_id: mark " +
                             std::to_string(s.mark_id) + " (camera " + std::to_string(s.camera) +
                             ") is not in the survey " + o.survey_origin);
    if (!(s.sigma_px > 0) || !std::isfinite(s.sigma_px))
      throw CalibrationError(o.observations_origin + ": sigma_px: camera " +
                             std::to_string(s.camera) + ", mark " + std::to_string(s.mark_id) +
                             ": the centroid sigma must be > 0 (give it per row or --sigma-px)");
    if (!seen.insert({s.camera, s.mark_id}).second)
      throw CalibrationError(o.observations_origin + ": point_id: mark " +
                             std::to_string(s.mark_id) + " seen twice by camera " +
                             std::to_string(s.camera) + " (one row per camera and mark)");
    by_mark[s.mark_id].push_back(&s);
  }
  return by_mark;
}

int camera_slot(const camera::RigCalibration& rig, int camera_id) {
  for (size_t i = 0; i < rig.cameras.size(); ++i)
    if (rig.cameras[i].camera_id == camera_id) return static_cast<int>(i);
  return -1;
}

/// Triangulates one mark in the rig's frame; false (reason set) when it cannot be used.
bool triangulate_mark(const camera::RigCalibration& rig,
                      const std::vector<const MarkSighting*>& seen, TriangulatedMark& out,
                      std::string& reason) {
  if (seen.size() < 2) {
    reason = "seen by camera " + std::to_string(seen.front()->camera) +
             " only: a mark needs >= 2 cameras to be triangulated";
    return false;
  }
  std::vector<triangulate::Observation> obs(seen.size());
  std::vector<int> slots(seen.size());
  for (size_t i = 0; i < seen.size(); ++i) {
    slots[i] = camera_slot(rig, seen[i]->camera);
    const camera::CalibratedCamera& cam = rig.cameras[static_cast<size_t>(slots[i])];
    obs[i].model = &cam.model;
    obs[i].T_c_w = cam.T_c_w;
    obs[i].pixel_px = seen[i]->pixel_px;
    obs[i].sigma_px = seen[i]->sigma_px;
    out.mark.cameras.push_back(seen[i]->camera);
  }
  triangulate::Result tri;
  if (!triangulate::triangulate(obs, triangulate::Options{}, tri)) {
    reason = "triangulation failed (rays parallel, or the point behind a camera)";
    return false;
  }
  out.mark.p_r = tri.p_w;
  out.mark.reprojection_chi2 = tri.chi2;
  out.cov_centroid = tri.cov_centroid;
  // dp/dtheta = -K_i dpixel_i/dtheta for the parameters of observation i's camera
  // (host/pipeline's calibration loadings, here over the raw parameters).
  out.d_point_d_calibration =
      calibration_sensitivity(tri, slots, static_cast<int>(rig.cameras.size()));
  return true;
}

/// C^+ (eigenvalues above a relative floor inverted, the rest dropped) and the rank of C.
std::pair<MatrixXd, int> pseudo_inverse(const MatrixXd& C) {
  const geometry::SymmetricEigen e = geometry::symmetric_eigen(C);
  const double floor = 1e-9 * std::max(e.values.maxCoeff(), 1e-300);
  VectorXd inverse_values = VectorXd::Zero(e.values.size());
  int rank = 0;
  for (Eigen::Index i = 0; i < e.values.size(); ++i)
    if (e.values(i) > floor) {
      inverse_values(i) = 1.0 / e.values(i);
      ++rank;
    }
  return {e.vectors * inverse_values.asDiagonal() * e.vectors.transpose(), rank};
}

/// Pseudo-inverse quadratic form r^T C^+ r and the rank of C.
std::pair<double, int> pseudo_mahalanobis(const VectorXd& r, const MatrixXd& C) {
  const auto [W, rank] = pseudo_inverse(C);
  return {r.dot(W * r), rank};
}

/// The usable marks' fit inputs, in ascending id order.
struct MarkSet {
  std::vector<Vec3> q_w, p_r;
  std::vector<Mat3> cov_r;     ///< triangulation covariance (centroid + calibration)
  std::vector<double> sigma;   ///< survey, per axis
  std::vector<bool> included;  ///< in the fit (false: rejected as an outlier)
  int size() const { return static_cast<int>(q_w.size()); }
  int included_count() const {
    return static_cast<int>(std::count(included.begin(), included.end(), true));
  }
};

void check_not_collinear(const MarkSet& all, const RegistrationOptions& o) {
  Vec3 mean = Vec3::Zero();
  for (int i = 0; i < all.size(); ++i)
    if (all.included[static_cast<size_t>(i)]) mean += all.q_w[static_cast<size_t>(i)];
  const int n = all.included_count();
  mean /= n;
  Mat3 scatter = Mat3::Zero();
  for (int i = 0; i < all.size(); ++i)
    if (all.included[static_cast<size_t>(i)]) {
      const Vec3 d = all.q_w[static_cast<size_t>(i)] - mean;
      scatter += d * d.transpose() / n;
    }
  const VectorXd l = geometry::symmetric_eigen(scatter, false).values;  // ascending
  const double first = std::sqrt(std::max(l(2), 0.0)), second = std::sqrt(std::max(l(1), 0.0));
  if (!(second > o.collinearity_ratio * first)) {
    std::ostringstream s;
    s << o.survey_origin << ": marks: the " << n
      << " usable marks are (nearly) collinear (spread across their line " << second * 1e3
      << " mm, along it " << first * 1e3 << " mm; need a ratio >= " << o.collinearity_ratio
      << "): the rotation about that line is not determined; survey marks off the line";
    throw CalibrationError(s.str());
  }
}

using Matrix6X = Eigen::Matrix<double, 6, Eigen::Dynamic>;

/// Fits T_r_w to the included marks (estimation/pose: T_to_from with the "body" the frame mapped
/// from, here w). D_p, D_q: dxi/dp_m and dxi/dq_m for every mark, zero for the excluded ones.
pose::BodyFit fit_included(const MarkSet& all, Matrix6X& D_p, Matrix6X& D_q,
                           const RegistrationOptions& o) {
  MarkSet in;
  for (int i = 0; i < all.size(); ++i) {
    if (!all.included[static_cast<size_t>(i)]) continue;
    in.q_w.push_back(all.q_w[static_cast<size_t>(i)]);
    in.p_r.push_back(all.p_r[static_cast<size_t>(i)]);
    in.cov_r.push_back(all.cov_r[static_cast<size_t>(i)]);
    in.sigma.push_back(all.sigma[static_cast<size_t>(i)]);
  }
  pose::BodyFit fit;
  if (!pose::fit_body(pose::PointsInBody{in.q_w}, pose::PointsInWorld{in.p_r}, in.cov_r, in.sigma,
                      fit, 50))
    throw CalibrationError(o.survey_origin +
                           ": marks: the registration fit failed (singular normal matrix: marks "
                           "collinear or coincident?)");
  D_p = Matrix6X::Zero(6, 3 * all.size());
  D_q = Matrix6X::Zero(6, 3 * all.size());
  for (int i = 0, k = 0; i < all.size(); ++i) {
    if (!all.included[static_cast<size_t>(i)]) continue;
    D_p.middleCols<3>(3 * i) = fit.d_pose_d_point[static_cast<size_t>(k)];
    D_q.middleCols<3>(3 * i) = fit.d_pose_d_survey[static_cast<size_t>(k)];
    ++k;
  }
  return fit;
}

/// Residual tests: r = e + J xi_error with xi_error = D_p e (e = e_p - R e_q, the marks' total
/// errors, correlated through the calibration; D_p zero for excluded marks), so
/// C_r = P C_e P^T with P = I + J D_p exactly to first order, for used and rejected marks alike.
void test_residuals(const Transform& T_r_w, const MarkSet& all, const Matrix6X& D_p,
                    const MatrixXd& cov_errors, std::vector<MarkRegistration>& marks,
                    RegistrationResult& out) {
  const int n = all.size();
  MatrixXd P = MatrixXd::Identity(3 * n, 3 * n);
  VectorXd r(3 * n);
  for (int i = 0; i < n; ++i) {
    const Vec3 Rq = T_r_w.linear() * all.q_w[static_cast<size_t>(i)];
    Eigen::Matrix<double, 3, 6> J;  // dr_i/dxi = [[R q_i]x, -I]
    J.leftCols<3>() = geometry::skew(Rq);
    J.rightCols<3>() = -Mat3::Identity();
    P.middleRows<3>(3 * i) += J * D_p;
    r.segment<3>(3 * i) = all.p_r[static_cast<size_t>(i)] - (Rq + T_r_w.translation());
  }
  const MatrixXd C_r = P * cov_errors * P.transpose();
  std::vector<Eigen::Index> used;
  for (int i = 0; i < n; ++i)
    if (all.included[static_cast<size_t>(i)])
      for (int k = 0; k < 3; ++k)
        used.push_back(3 * i + k);
  const auto [W, rank] = pseudo_inverse(C_r(used, used));
  out.chi2 = r(used).dot(W * r(used));
  out.dof = rank;
  // Scale: triangulated = (1 + s) T surveyed adds s R q_i to mark i's error, so r = P (e + s a),
  // a_i = R q_i (the rigid part of a, and the origin, the fit absorbs through P): generalised
  // least squares for s over the used marks.
  VectorXd a(3 * n);
  for (int i = 0; i < n; ++i)
    a.segment<3>(3 * i) = T_r_w.linear() * all.q_w[static_cast<size_t>(i)];
  const VectorXd b = (P * a)(used);
  const double information = b.dot(W * b);
  out.scale_error = information > 0 ? b.dot(W * r(used)) / information : 0;
  out.scale_error_sigma = information > 0 ? 1 / std::sqrt(information) : HUGE_VAL;
  using uncertainty::DegreesOfFreedom;
  out.p_value =
      out.dof > 0 ? uncertainty::chi_square_survival(out.chi2, DegreesOfFreedom(out.dof)) : 1.0;
  for (int i = 0; i < n; ++i) {
    MarkRegistration& m = marks[static_cast<size_t>(i)];
    m.used = all.included[static_cast<size_t>(i)];
    m.residual_r = r.segment<3>(3 * i);
    std::tie(m.chi2, m.dof) =
        pseudo_mahalanobis(m.residual_r, MatrixXd(C_r.block(3 * i, 3 * i, 3, 3)));
    m.p_value = m.dof > 0 ? uncertainty::chi_square_survival(m.chi2, DegreesOfFreedom(m.dof)) : 1.0;
  }
}

/// The used mark with the smallest p-value below false_alarm / (used marks), or -1.
int worst_failing_mark(const std::vector<MarkRegistration>& marks, int used_count,
                       double false_alarm) {
  int worst = -1;
  for (size_t i = 0; i < marks.size(); ++i)
    if (marks[i].used && marks[i].p_value < false_alarm / used_count &&
        (worst < 0 || marks[i].p_value < marks[static_cast<size_t>(worst)].p_value))
      worst = static_cast<int>(i);
  return worst;
}

/// d(left perturbation of T^-1)/d(left perturbation of T): phi' = -R^T phi,
/// rho' = -R^T [t]x phi - R^T rho.
Mat6 inverse_jacobian(const Transform& T) {
  const Mat3 Rt = T.linear().transpose();
  Mat6 D = Mat6::Zero();
  D.topLeftCorner<3, 3>() = -Rt;
  D.bottomLeftCorner<3, 3>() = -Rt * geometry::skew(T.translation());
  D.bottomRightCorner<3, 3>() = -Rt;
  return D;
}

Mat6 symmetric(const Mat6& C) {
  return 0.5 * (C + C.transpose());
}

/// Every camera's T_c_w = T_c_r T_r_w and the joint covariance of (intrinsics, xi_c_w):
/// psi = M theta + N xi_noise, xi_noise the centroid and survey part of xi_r_w.
void compose_registered_rig(const camera::RigCalibration& rig, const MatrixXd& cov_theta,
                            const Eigen::Matrix<double, 6, Eigen::Dynamic>& d_rw_d_theta,
                            const Mat6& cov_rw_noise, RegistrationResult& out) {
  const int cameras = static_cast<int>(rig.cameras.size());
  MatrixXd M = MatrixXd::Identity(kBlock * cameras, kBlock * cameras);
  MatrixXd N = MatrixXd::Zero(kBlock * cameras, 6);
  out.registered = rig;
  for (int c = 0; c < cameras; ++c) {
    camera::CalibratedCamera& cam = out.registered.cameras[static_cast<size_t>(c)];
    Mat6 d_cw_d_cr, d_cw_d_rw;
    geometry::composition_jacobians(cam.T_c_w, out.T_r_w, d_cw_d_cr, d_cw_d_rw);
    const int row = kBlock * c + kExtrinsicOffset;
    M.block<6, 6>(row, row) = d_cw_d_cr;
    M.middleRows(row, 6) += d_cw_d_rw * d_rw_d_theta;
    N.middleRows(row, 6) = d_cw_d_rw;
    cam.T_c_w = cam.T_c_w * out.T_r_w;
  }
  out.joint_covariance = M * cov_theta * M.transpose() + N * cov_rw_noise * N.transpose();
  out.joint_covariance = 0.5 * (out.joint_covariance + out.joint_covariance.transpose()).eval();
  camera::set_joint_covariance(out.registered, out.joint_covariance);  // file version 2
}

/// The fit register_rig and register_body share, written in register_rig's frames: the marks
/// triangulated through `rig_r` in its frame (S_r) against the survey (S_w) give T_r_w and every
/// field of the result but T_w_r, cov_T_w_r, registered and joint_covariance. `d_rw_d_theta`:
/// d(xi_r_w)/d(calibration parameters).
RegistrationResult fit_survey(const camera::RigCalibration& rig_r,
                              const Eigen::MatrixXd& calibration_covariance,
                              const survey::RigidBodySurvey& survey_w,
                              const std::vector<MarkSighting>& sightings,
                              const RegistrationOptions& o, Matrix6X& d_rw_d_theta) {
  const int parameters = kBlock * static_cast<int>(rig_r.cameras.size());
  if (calibration_covariance.rows() != parameters || calibration_covariance.cols() != parameters)
    throw CalibrationError(o.rig_origin + ": joint covariance: expected " +
                           std::to_string(parameters) + " x " + std::to_string(parameters));
  RegistrationResult out;
  std::vector<TriangulatedMark> usable;
  for (const auto& [id, seen] : group_sightings(rig_r, survey_w, sightings, o)) {
    TriangulatedMark t;
    t.mark.mark_id = id;
    std::string reason;
    if (!triangulate_mark(rig_r, seen, t, reason)) {
      out.skipped.push_back(
          {id, o.observations_origin + ": mark " + std::to_string(id) + ": " + reason});
      continue;
    }
    const survey::SurveyedMark* s = survey_w.find(id);
    t.mark.q_w = s->p_body;
    t.mark.survey_sigma_m = s->sigma_m;
    usable.push_back(std::move(t));
  }
  if (usable.size() < 3) {
    std::vector<int> ids;
    for (const auto& t : usable)
      ids.push_back(t.mark.mark_id);
    std::string why = o.observations_origin + ": point_id: " + std::to_string(usable.size()) +
                      " usable marks (" + list_ids(ids) +
                      "), need >= 3 non-collinear (the survey " + o.survey_origin + " has " +
                      std::to_string(survey_w.marks.size()) + " marks)";
    for (const SkippedMark& s : out.skipped)
      why += "; " + s.reason;
    throw CalibrationError(why);
  }

  // Joint covariance of the triangulated points: centroid (independent per mark) + calibration.
  const int n = static_cast<int>(usable.size());
  MatrixXd G(3 * n, parameters);
  MatrixXd cov_centroid = MatrixXd::Zero(3 * n, 3 * n);
  for (int i = 0; i < n; ++i) {
    G.middleRows(3 * i, 3) = usable[static_cast<size_t>(i)].d_point_d_calibration;
    cov_centroid.block<3, 3>(3 * i, 3 * i) = usable[static_cast<size_t>(i)].cov_centroid;
  }
  const MatrixXd cov_points = cov_centroid + G * calibration_covariance * G.transpose();
  std::vector<Vec3> q_w(usable.size()), p_r(usable.size());
  std::vector<Mat3> cov_r(usable.size());
  std::vector<double> sigma(usable.size());
  for (int i = 0; i < n; ++i) {
    MarkRegistration& m = usable[static_cast<size_t>(i)].mark;
    m.cov_r = cov_points.block<3, 3>(3 * i, 3 * i);
    q_w[static_cast<size_t>(i)] = m.q_w;
    p_r[static_cast<size_t>(i)] = m.p_r;
    cov_r[static_cast<size_t>(i)] = m.cov_r;
    sigma[static_cast<size_t>(i)] = m.survey_sigma_m;
  }
  MarkSet all;
  for (int i = 0; i < n; ++i) {
    MarkRegistration& m = usable[static_cast<size_t>(i)].mark;
    m.cov_r = cov_points.block<3, 3>(3 * i, 3 * i);
    all.q_w.push_back(m.q_w);
    all.p_r.push_back(m.p_r);
    all.cov_r.push_back(m.cov_r);
    all.sigma.push_back(m.survey_sigma_m);
    out.marks.push_back(m);
  }
  all.included.assign(static_cast<size_t>(n), true);
  check_not_collinear(all, o);
  std::vector<double> weights(static_cast<size_t>(n));  // the fit's own start, for the report
  for (size_t i = 0; i < weights.size(); ++i)
    weights[i] = 1.0 / (all.cov_r[i].trace() / 3.0 + all.sigma[i] * all.sigma[i]);
  pose::absolute_orientation(pose::PointsInBody{all.q_w}, pose::PointsInWorld{all.p_r}, weights,
                             out.T_r_w_start);
  // The marks' total errors e = e_p - R e_q: survey errors isotropic, so R s^2 I R^T = s^2 I.
  MatrixXd cov_errors = cov_points;
  for (int i = 0; i < n; ++i)
    cov_errors.block<3, 3>(3 * i, 3 * i) +=
        all.sigma[static_cast<size_t>(i)] * all.sigma[static_cast<size_t>(i)] * Mat3::Identity();

  // Fit, test, reject the worst failing mark, refit, while one fails and more than 3 remain.
  Matrix6X D_p, D_q;
  for (;;) {
    const pose::BodyFit fit = fit_included(all, D_p, D_q, o);
    out.T_r_w = fit.T_w_b;
    out.iterations = fit.iterations;
    test_residuals(out.T_r_w, all, D_p, cov_errors, out.marks, out);
    const int worst = worst_failing_mark(out.marks, all.included_count(), o.outlier_false_alarm);
    if (worst < 0 || !o.reject_outliers || all.included_count() <= 3) break;
    all.included[static_cast<size_t>(worst)] = false;
    check_not_collinear(all, o);
  }
  const int used_count = all.included_count();
  for (MarkRegistration& m : out.marks)
    m.outlier = !m.used || m.p_value < o.outlier_false_alarm / used_count;

  // xi_r_w = D_p e_p + D_q e_q (first order); e_p = centroid + G theta.
  d_rw_d_theta = D_p * G;
  out.cov_T_r_w_centroid = symmetric(D_p * cov_centroid * D_p.transpose());
  out.cov_T_r_w_calibration =
      symmetric(d_rw_d_theta * calibration_covariance * d_rw_d_theta.transpose());
  for (int i = 0; i < n; ++i) {
    const double s2 = all.sigma[static_cast<size_t>(i)] * all.sigma[static_cast<size_t>(i)];
    out.cov_T_r_w_survey += s2 * D_q.middleCols<3>(3 * i) * D_q.middleCols<3>(3 * i).transpose();
  }
  out.cov_T_r_w_survey = symmetric(out.cov_T_r_w_survey);
  out.cov_T_r_w = out.cov_T_r_w_centroid + out.cov_T_r_w_calibration + out.cov_T_r_w_survey;
  return out;
}

}  // namespace

RegistrationResult register_rig(const camera::RigCalibration& rig_r,
                                const Eigen::MatrixXd& calibration_covariance,
                                const survey::RigidBodySurvey& survey_w,
                                const std::vector<MarkSighting>& sightings,
                                const RegistrationOptions& o) {
  if (survey_w.frame != 'w')
    throw CalibrationError(o.survey_origin + ": frame: the survey is in frame '" +
                           std::string(1, survey_w.frame) +
                           "'; registration needs the marks in the world frame 'w' "
                           "(docs/conventions.md)");
  Matrix6X d_rw_d_theta;
  RegistrationResult out =
      fit_survey(rig_r, calibration_covariance, survey_w, sightings, o, d_rw_d_theta);
  out.T_w_r = out.T_r_w.inverse();
  const Mat6 d_wr_d_rw = inverse_jacobian(out.T_r_w);
  out.cov_T_w_r = symmetric(d_wr_d_rw * out.cov_T_r_w * d_wr_d_rw.transpose());
  compose_registered_rig(rig_r, calibration_covariance, d_rw_d_theta,
                         out.cov_T_r_w_centroid + out.cov_T_r_w_survey, out);
  return out;
}

BodyRegistration register_body(const camera::RigCalibration& rig_w,
                               const Eigen::MatrixXd& calibration_covariance,
                               const survey::RigidBodySurvey& survey_b,
                               const std::vector<MarkSighting>& sightings,
                               const RegistrationOptions& o) {
  if (survey_b.frame == 'w')
    throw CalibrationError(o.survey_origin +
                           ": frame: the survey is in the world frame 'w': "
                           "that registers the rig (register_rig), not a body; a body survey "
                           "is in its own frame ('p' pylon, 's' store)");
  BodyRegistration out;
  // register_rig's fit with S_w as the rig's frame and the body's frame as the surveyed one.
  const RegistrationResult fit =
      fit_survey(rig_w, calibration_covariance, survey_b, sightings, o, out.d_T_w_b_d_calibration);
  out.body = survey_b.name;
  out.frame = survey_b.frame;
  out.T_w_b_start = fit.T_r_w_start;
  out.T_w_b = fit.T_r_w;
  out.cov_T_w_b = fit.cov_T_r_w;
  out.cov_T_w_b_centroid = fit.cov_T_r_w_centroid;
  out.cov_T_w_b_calibration = fit.cov_T_r_w_calibration;
  out.cov_T_w_b_survey = fit.cov_T_r_w_survey;
  for (const MarkRegistration& m : fit.marks)
    out.marks.push_back({m.mark_id, m.cameras, m.p_r, m.cov_r, m.q_w, m.survey_sigma_m,
                         m.reprojection_chi2, m.residual_r, m.chi2, m.dof, m.p_value, m.used,
                         m.outlier});
  out.skipped = fit.skipped;
  out.chi2 = fit.chi2;
  out.dof = fit.dof;
  out.p_value = fit.p_value;
  out.iterations = fit.iterations;
  out.scale_error = fit.scale_error;
  out.scale_error_sigma = fit.scale_error_sigma;
  return out;
}

RelativePose relative_pose(const BodyRegistration& a, const BodyRegistration& b,
                           const Eigen::MatrixXd& calibration_covariance) {
  if (a.d_T_w_b_d_calibration.cols() != calibration_covariance.rows() ||
      b.d_T_w_b_d_calibration.cols() != calibration_covariance.rows())
    throw CalibrationError("relative pose: the registrations of " + a.body + " and " + b.body +
                           " are not through the rig of this calibration covariance");
  RelativePose out;
  const Transform T_a_w = a.T_w_b.inverse();
  out.T_a_b = T_a_w * b.T_w_b;
  Mat6 d_ab_d_aw, d_ab_d_wb;
  geometry::composition_jacobians(T_a_w, b.T_w_b, d_ab_d_aw, d_ab_d_wb);
  const Mat6 d_ab_d_wa = d_ab_d_aw * inverse_jacobian(a.T_w_b);
  const Matrix6X d_ab_d_theta =
      d_ab_d_wa * a.d_T_w_b_d_calibration + d_ab_d_wb * b.d_T_w_b_d_calibration;
  const Mat6 noise_a = a.cov_T_w_b_centroid + a.cov_T_w_b_survey;
  const Mat6 noise_b = b.cov_T_w_b_centroid + b.cov_T_w_b_survey;
  out.cov_T_a_b = symmetric(d_ab_d_theta * calibration_covariance * d_ab_d_theta.transpose() +
                            d_ab_d_wa * noise_a * d_ab_d_wa.transpose() +
                            d_ab_d_wb * noise_b * d_ab_d_wb.transpose());
  return out;
}

}  // namespace storetrack::calib
