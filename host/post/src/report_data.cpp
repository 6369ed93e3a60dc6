#include "report_data.hpp"

#include <cmath>
#include <map>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "storetrack/uncertainty/spd_inverse.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::post {

namespace {

using uncertainty::chi_square_quantile;
using uncertainty::DegreesOfFreedom;
using uncertainty::Probability;

const msg::MarkObservations* delivered(const pipeline::AlignedExposure& e, int camera_id) {
  for (const msg::MarkObservations& c : e.cameras)
    if (c.camera_id == camera_id) return &c;
  return nullptr;
}

// The window's RMS band: sqrt(chi-square quantile / dof).
void set_band(ResidualWindow& w) {
  w.rms_normalised = std::sqrt(w.chi2 / w.dof);
  const DegreesOfFreedom dof(std::max(1, static_cast<int>(std::lround(w.dof))));
  const double tail = (1.0 - kResidualBandProbability) / 2;
  w.band_low = std::sqrt(chi_square_quantile(Probability(tail), dof) / dof.value);
  w.band_high = std::sqrt(chi_square_quantile(Probability(1 - tail), dof) / dof.value);
}

// A view's pixel loadings on the calibration factors, d pixel / dz (2 x factors), through the
// one implementation of a view's calibration loadings with the pixel as its "point" (K = -[I 0]^T
// makes -K d pixel / d theta F the pixel's own loadings).
Eigen::Matrix<double, 2, Eigen::Dynamic> pixel_loadings(const uncertainty::CalibrationFactors& f,
                                                        int slot,
                                                        const camera::ProjectionJacobians& J) {
  Eigen::Matrix<double, 3, 2> K = Eigen::Matrix<double, 3, 2>::Zero();
  K.topRows<2>() = -Eigen::Matrix2d::Identity();
  uncertainty::Loadings3 L = uncertainty::Loadings3::Zero(3, f.num_factors());
  geometry::Mat3 by_intrinsic = geometry::Mat3::Zero(), by_extrinsic = geometry::Mat3::Zero();
  uncertainty::add_observation_loadings(f, slot, K, J, L, by_intrinsic, by_extrinsic);
  return L.topRows<2>();
}

// The rows that keep a residual block's `rank` directions (its eigenvectors of the largest
// eigenvalues): a rank-1 block is singular, its residual lies on the major axis, and the tiny
// minor eigenvalue left by rounding or by a slightly different hat matrix must not weigh.
Eigen::Matrix<double, Eigen::Dynamic, 2> kept_rows(const Eigen::Matrix2d& block, int rank) {
  if (rank >= 2) return Eigen::Matrix2d::Identity();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eigen(block);
  return eigen.eigenvectors().col(1).transpose();  // eigenvalues ascending
}

// The row of one rig camera at an exposure, before its views are added.
CameraResidualRow new_row(const pipeline::AlignedExposure& e, const pipeline::ExposureResult& r,
                          int camera_id) {
  CameraResidualRow row;
  row.trigger_seq = e.trigger_seq;
  row.t_tai_ns = r.reference_mid_tai_ns;
  row.camera_id = camera_id;
  const msg::MarkObservations* obs = delivered(e, camera_id);
  row.delivered = obs != nullptr;
  if (obs) row.marks_reported = static_cast<int>(obs->marks.size());
  return row;
}

}  // namespace

std::vector<ResidualDiagnostics::View> mark_views(const pipeline::MarkResult& m,
                                                  const camera::RigCalibration& rig,
                                                  const uncertainty::CalibrationFactors& factors) {
  const std::size_t n = m.observations.size();
  std::vector<ResidualDiagnostics::View> views(n);
  std::vector<Eigen::Matrix<double, 2, 3>> J(n);
  std::vector<Eigen::Matrix<double, 2, Eigen::Dynamic>> P(n);
  geometry::Mat3 H = geometry::Mat3::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    const auto& o = m.observations[i];
    const camera::CalibratedCamera* c = rig.find(o.camera_id);
    camera::ProjectionJacobians jac;
    if (!c || !c->model.project_world(c->T_c_w, m.p_w, &jac)) return {};
    views[i].slot = static_cast<int>(c - rig.cameras.data());
    views[i].rank = n == 2 ? 1 : 2;
    views[i].residual_px = o.residual_px;
    J[i] = jac.d_point_world;
    P[i] = pixel_loadings(factors, views[i].slot, jac);
    H += J[i].transpose() * o.information_px * J[i];
  }
  geometry::Mat3 H_inv;
  if (!uncertainty::inverse_spd<3>(H, H_inv)) return {};
  // (I - A)_ij = delta_ij I - J_i H^-1 J_j^T W_j: view i's residual per pixel error of view j.
  for (std::size_t i = 0; i < n; ++i) {
    views[i].calibration_loadings.setZero(2, factors.num_factors());
    for (std::size_t j = 0; j < n; ++j) {
      Eigen::Matrix2d G = -J[i] * H_inv * J[j].transpose() * m.observations[j].information_px;
      if (i == j) G += Eigen::Matrix2d::Identity();
      const double var = m.observations[j].sigma_px * m.observations[j].sigma_px;
      views[i].noise_cov += var * G * G.transpose();
      views[i].calibration_loadings += G * P[j];
    }
  }
  return views;
}

ResidualDiagnostics::ResidualDiagnostics(const camera::RigCalibration& rig,
                                         const uncertainty::CalibrationFactors& factors)
    : rig_(rig), factors_(factors) {}

std::vector<CameraResidualRow> ResidualDiagnostics::add(const pipeline::AlignedExposure& e,
                                                        const pipeline::ExposureResult& r) {
  if (!span_started_) span_first_seq_ = e.trigger_seq;
  span_started_ = true;
  span_last_seq_ = e.trigger_seq;
  std::vector<CameraResidualRow> rows;
  for (const camera::CalibratedCamera& camera : rig_.cameras)
    rows.push_back(new_row(e, r, camera.camera_id));
  for (const pipeline::MarkResult& m : r.marks) {
    if (m.excluded || m.observations.size() < 2 || m.id < 0) continue;
    const std::vector<View> views = mark_views(m, rig_, factors_);
    std::uint32_t camera_set = 0;
    for (const View& v : views)
      camera_set |= 1u << (v.slot % 32);
    for (const View& v : views) {
      CameraResidualRow& row = rows[static_cast<std::size_t>(v.slot)];
      if (row.delivered) add_view(e.trigger_seq, Key{v.slot, m.body, m.id}, camera_set, v, row);
    }
  }
  return rows;
}

void ResidualDiagnostics::add_view(std::uint32_t seq, const Key& key, std::uint32_t camera_set,
                                   const View& v, CameraResidualRow& row) {
  ++row.residuals;
  Mean& mean = means_[key];
  if (mean.views == 0) mean.loadings.setZero(2, factors_.num_factors());
  ++mean.views;
  mean.rank = std::max(mean.rank, v.rank);
  mean.residual_px += v.residual_px;
  mean.noise_cov += v.noise_cov;
  mean.loadings += v.calibration_loadings;
  // Noise part: pair with the previous exposure's view of the same mark by the same camera set
  // (the same hat matrix, so the calibration part cancels to its change over one exposure).
  const auto it = pending_.find(key);
  if (it == pending_.end() || it->second.trigger_seq + 1 != seq ||
      it->second.camera_set != camera_set) {
    pending_[key] = Pending{seq, camera_set, v.residual_px, v.noise_cov, v.rank};
    return;
  }
  const Eigen::Matrix2d C = v.noise_cov + it->second.noise_cov;
  const Eigen::Matrix<double, Eigen::Dynamic, 2> T = kept_rows(C, v.rank);
  const Eigen::VectorXd d = T * (v.residual_px - it->second.residual_px);
  const Eigen::LLT<Eigen::MatrixXd> llt(T * C * T.transpose());
  if (llt.info() == Eigen::Success) {
    ++row.differences;
    row.noise_chi2 += d.dot(llt.solve(d));
    row.noise_dof += static_cast<double>(T.rows());
  }
  pending_.erase(it);  // pairs do not overlap: the next difference is independent of this one
}

void ResidualDiagnostics::use_calibration(const camera::RigCalibration& rig,
                                          const uncertainty::CalibrationFactors& factors) {
  for (const CalibrationResidual& c : span_residuals())
    closed_spans_.push_back(c);
  means_.clear();
  pending_.clear();
  rig_ = rig;
  factors_ = factors;
  ++span_;
  span_started_ = false;
}

std::vector<CalibrationResidual> ResidualDiagnostics::calibration_residuals() const {
  std::vector<CalibrationResidual> out = closed_spans_;
  for (const CalibrationResidual& c : span_residuals())
    out.push_back(c);
  // One test per camera and span: each band at 1 - 0.05 / tests (Bonferroni), so a correct
  // calibration has any of them outside with probability at most 0.05.
  const double probability = calibration_band_probability(static_cast<int>(out.size()));
  for (CalibrationResidual& c : out) {
    const DegreesOfFreedom dof(static_cast<int>(c.dof));
    const double tail = (1.0 - probability) / 2;
    c.band_probability = probability;
    c.band_low = chi_square_quantile(Probability(tail), dof);
    c.band_high = chi_square_quantile(Probability(1 - tail), dof);
  }
  return out;
}

std::vector<CalibrationResidual> ResidualDiagnostics::span_residuals() const {
  std::vector<CalibrationResidual> out;
  for (int slot = 0; slot < static_cast<int>(rig_.cameras.size()); ++slot) {
    std::vector<const Mean*> means;
    for (const auto& [key, mean] : means_)
      if (std::get<0>(key) == slot) means.push_back(&mean);
    if (means.empty()) continue;
    const auto stacked = static_cast<Eigen::Index>(2 * means.size());
    Eigen::VectorXd r_bar(stacked);
    Eigen::MatrixXd M_bar(stacked, factors_.num_factors());
    Eigen::MatrixXd N_bar = Eigen::MatrixXd::Zero(stacked, stacked);
    CalibrationResidual c;
    c.camera_id = rig_.cameras[static_cast<std::size_t>(slot)].camera_id;
    c.span = span_;
    c.first_trigger_seq = span_first_seq_;
    c.last_trigger_seq = span_last_seq_;
    for (std::size_t i = 0; i < means.size(); ++i) {
      const Mean& m = *means[i];
      const double n = m.views;
      const auto row = static_cast<Eigen::Index>(2 * i);
      r_bar.segment<2>(row) = m.residual_px / n;
      M_bar.middleRows(row, 2) = m.loadings / n;
      N_bar.block<2, 2>(row, row) = m.noise_cov / (n * n);  // independent noise per exposure
      c.views += m.views;
    }
    // Each mark's kept directions (a mark always seen by two cameras: its major axis).
    Eigen::MatrixXd T = Eigen::MatrixXd::Zero(stacked, stacked);
    Eigen::Index dim = 0;
    for (std::size_t i = 0; i < means.size(); ++i) {
      const auto row = static_cast<Eigen::Index>(2 * i);
      const Eigen::Matrix2d block =
          M_bar.middleRows(row, 2) * M_bar.middleRows(row, 2).transpose() +
          N_bar.block<2, 2>(row, row);
      const Eigen::Matrix<double, Eigen::Dynamic, 2> kept = kept_rows(block, means[i]->rank);
      T.block(dim, row, kept.rows(), 2) = kept;
      dim += kept.rows();
    }
    T.conservativeResize(dim, stacked);
    r_bar = T * r_bar;
    M_bar = T * M_bar;
    N_bar = T * N_bar * T.transpose();
    const Eigen::MatrixXd calibration = M_bar * M_bar.transpose();
    const Eigen::MatrixXd predicted = calibration + N_bar;
    const Eigen::LLT<Eigen::MatrixXd> llt(predicted);
    if (llt.info() != Eigen::Success) continue;
    c.marks = static_cast<int>(means.size());
    c.chi2 = r_bar.dot(llt.solve(r_bar));
    c.dof = static_cast<double>(dim);
    c.calibration_share = calibration.trace() / predicted.trace();
    out.push_back(c);
  }
  return out;
}

ExposureRow exposure_row(const pipeline::AlignedExposure& e, const pipeline::ExposureResult& r,
                         bool written) {
  ExposureRow row;
  row.trigger_seq = e.trigger_seq;
  row.t_tai_ns = r.reference_mid_tai_ns;
  row.written = written;
  row.cameras_delivered = static_cast<int>(e.cameras.size());
  row.missing_camera_mask = e.missing_camera_mask;
  row.closed_by_timeout = e.closed_by_timeout;
  if (r.T_w_s.valid) {
    row.store_marks = r.T_w_s.marks_used;
    row.store_chi2 = r.T_w_s.chi2;
  }
  if (r.T_w_p.valid) {
    row.pylon_marks = r.T_w_p.marks_used;
    row.pylon_chi2 = r.T_w_p.chi2;
  }
  return row;
}

std::vector<ResidualWindow> residual_windows(std::span<const CameraResidualRow> rows, int window) {
  std::map<int, ResidualWindow> open;  // per camera, the window being filled
  std::vector<ResidualWindow> out;
  for (const CameraResidualRow& row : rows) {
    if (!row.delivered) continue;
    ResidualWindow& w = open[row.camera_id];
    if (w.exposures == 0) {
      w.camera_id = row.camera_id;
      w.first_seq = row.trigger_seq;
      w.first_t_tai_ns = row.t_tai_ns;
    }
    ++w.exposures;
    w.residuals += row.differences;
    w.chi2 += row.noise_chi2;
    w.dof += row.noise_dof;
    w.last_seq = row.trigger_seq;
    w.last_t_tai_ns = row.t_tai_ns;
    if (w.exposures < window) continue;
    if (w.dof > 0) {
      set_band(w);
      out.push_back(w);
    }
    w = ResidualWindow{};
  }
  return out;
}

WindowsInside windows_inside(std::span<const ResidualWindow> windows) {
  WindowsInside x;
  for (const ResidualWindow& w : windows) {
    ++x.windows;
    x.inside += w.inside() ? 1 : 0;
  }
  if (x.windows == 0) return x;
  const auto band = uncertainty::binomial_interval(x.windows, kResidualBandProbability, 0.025);
  x.band_low = band.low;
  x.band_high = band.high;
  return x;
}

ChiSquareExceedance rigid_exceedance(std::span<const ExposureRow> rows, bool store,
                                     double probability) {
  ChiSquareExceedance x;
  x.probability = probability;
  for (const ExposureRow& row : rows) {
    const int marks = store ? row.store_marks : row.pylon_marks;
    if (!row.written || marks < 3) continue;
    ++x.fits;
    const double q = chi_square_quantile(Probability(probability), DegreesOfFreedom(3 * marks - 6));
    if ((store ? row.store_chi2 : row.pylon_chi2) > q) ++x.above;
  }
  if (x.fits == 0) return x;
  const auto band = uncertainty::binomial_interval(x.fits, 1 - probability, 0.025);
  x.band_low = band.low;
  x.band_high = band.high;
  return x;
}

}  // namespace storetrack::post
