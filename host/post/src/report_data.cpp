#include "report_data.hpp"

#include <cmath>
#include <map>

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

// Each view's degrees of freedom in its mark's triangulation, 2 - leverage (empty when a view's
// camera is not in the rig or the point is behind it).
std::vector<double> view_dof(const pipeline::MarkResult& m, const camera::RigCalibration& rig) {
  std::vector<Eigen::Matrix<double, 2, 3>> J;
  geometry::Mat3 H = geometry::Mat3::Zero();
  for (const auto& o : m.observations) {
    const camera::CalibratedCamera* c = rig.find(o.camera_id);
    camera::ProjectionJacobians jac;
    if (!c || !c->model.project_world(c->T_c_w, m.p_w, &jac)) return {};
    J.push_back(jac.d_point_world);
    H += jac.d_point_world.transpose() * o.information_px * jac.d_point_world;
  }
  geometry::Mat3 H_inv;
  if (!uncertainty::inverse_spd<3>(H, H_inv)) return {};
  std::vector<double> dof;
  for (std::size_t i = 0; i < J.size(); ++i)
    dof.push_back(2.0 -
                  (J[i] * H_inv * J[i].transpose() * m.observations[i].information_px).trace());
  return dof;
}

// The views of the row's camera in the exposure's triangulations (marks of >= 2 views): count,
// sum of r^T W r, and their degrees of freedom.
void add_residuals(const pipeline::ExposureResult& r, const camera::RigCalibration& rig,
                   CameraResidualRow& row) {
  for (const pipeline::MarkResult& m : r.marks) {
    if (m.excluded || m.observations.size() < 2) continue;
    std::vector<double> dof;
    for (std::size_t i = 0; i < m.observations.size(); ++i) {
      const auto& o = m.observations[i];
      if (o.camera_id != row.camera_id) continue;
      if (dof.empty()) dof = view_dof(m, rig);
      if (dof.empty()) break;
      ++row.residuals;
      row.chi2 += o.residual_px.dot(o.information_px * o.residual_px);
      row.dof += dof[i];
    }
  }
}

// The window's RMS band: sqrt(chi-square quantile / dof).
void set_band(ResidualWindow& w) {
  w.rms_normalised = std::sqrt(w.chi2 / w.dof);
  const DegreesOfFreedom dof(std::max(1, static_cast<int>(std::lround(w.dof))));
  const double tail = (1.0 - kResidualBandProbability) / 2;
  w.band_low = std::sqrt(chi_square_quantile(Probability(tail), dof) / dof.value);
  w.band_high = std::sqrt(chi_square_quantile(Probability(1 - tail), dof) / dof.value);
}

}  // namespace

std::vector<CameraResidualRow> camera_residual_rows(const pipeline::AlignedExposure& e,
                                                    const pipeline::ExposureResult& r,
                                                    const camera::RigCalibration& rig) {
  std::vector<CameraResidualRow> rows;
  for (const camera::CalibratedCamera& camera : rig.cameras) {
    const int id = camera.camera_id;
    CameraResidualRow row;
    row.trigger_seq = e.trigger_seq;
    row.t_tai_ns = r.reference_mid_tai_ns;
    row.camera_id = id;
    const msg::MarkObservations* obs = delivered(e, id);
    row.delivered = obs != nullptr;
    if (obs) {
      row.marks_reported = static_cast<int>(obs->marks.size());
      add_residuals(r, rig, row);
    }
    rows.push_back(row);
  }
  return rows;
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
    w.residuals += row.residuals;
    w.chi2 += row.chi2;
    w.dof += row.dof;
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
