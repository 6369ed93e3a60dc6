#include "centroid_eval.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>

namespace storetrack::centroid::eval {

CramerRao cramer_rao(sim::SpotRenderer& renderer, const sim::Spot& spot,
                     const sim::SensorModel& sensor, int width, int height) {
  sim::PixelBox box = sim::spot_box(spot, width, height);
  CramerRao out;
  if (box.empty()) {
    out.sigma_x_px = out.sigma_y_px = out.sigma_px = std::numeric_limits<double>::infinity();
    return out;
  }
  const size_t n = static_cast<size_t>(box.width()) * box.height();
  std::vector<double> mu(n), xp(n), xm(n), yp(n), ym(n);
  constexpr double kStep = 1e-3;  // px; the expected image is smooth (erf-integrated)
  sim::Spot s = spot;
  renderer.evaluate(s, box, mu.data());
  s.x_px = spot.x_px + kStep;
  renderer.evaluate(s, box, xp.data());
  s.x_px = spot.x_px - kStep;
  renderer.evaluate(s, box, xm.data());
  s = spot;
  s.y_px = spot.y_px + kStep;
  renderer.evaluate(s, box, yp.data());
  s.y_px = spot.y_px - kStep;
  renderer.evaluate(s, box, ym.data());
  const double other_var = sensor.background_e + sensor.read_noise_e * sensor.read_noise_e +
                           sensor.gain_e_per_dn * sensor.gain_e_per_dn / 12.0;
  Eigen::Matrix3d fisher = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d jac((xp[i] - xm[i]) / (2 * kStep), (yp[i] - ym[i]) / (2 * kStep),
                              mu[i] / spot.flux_e);
    fisher += jac * jac.transpose() / (mu[i] + other_var);
  }
  const Eigen::Matrix3d cov = fisher.inverse();
  out.sigma_x_px = std::sqrt(cov(0, 0));
  out.sigma_y_px = std::sqrt(cov(1, 1));
  out.sigma_px = std::sqrt(0.5 * (cov(0, 0) + cov(1, 1)));
  return out;
}

std::vector<sim::Spot> random_spots(const sim::Spot& prototype, int count, int width, int height,
                                    double margin, double min_spacing, std::mt19937_64& rng) {
  // Jittered grid: as many cells as needed with the frame's aspect ratio, one spot per cell.
  const double usable_w = width - 2 * margin, usable_h = height - 2 * margin;
  int cols = std::max(1, static_cast<int>(std::ceil(std::sqrt(count * usable_w / usable_h))));
  int rows = (count + cols - 1) / cols;
  const double cell_w = usable_w / cols, cell_h = usable_h / rows;
  const double jitter_w = std::max(0.0, cell_w - min_spacing);
  const double jitter_h = std::max(0.0, cell_h - min_spacing);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  std::vector<sim::Spot> spots;
  for (int k = 0; k < count; ++k) {
    sim::Spot s = prototype;
    const int r = k / cols, c = k % cols;
    s.x_px = margin + c * cell_w + 0.5 * (cell_w - jitter_w) + jitter_w * u01(rng);
    s.y_px = margin + r * cell_h + 0.5 * (cell_h - jitter_h) + jitter_h * u01(rng);
    spots.push_back(s);
  }
  return spots;
}

std::vector<Match> match(std::span<const sim::Spot> truth, std::span<const Blob> blobs,
                         double radius_px) {
  std::vector<Match> matches;
  for (size_t t = 0; t < truth.size(); ++t) {
    Match m;
    m.truth = static_cast<int>(t);
    double best = radius_px * radius_px;
    for (size_t b = 0; b < blobs.size(); ++b) {
      const double ex = blobs[b].x_px - truth[t].x_px, ey = blobs[b].y_px - truth[t].y_px;
      if (ex * ex + ey * ey <= best) {
        best = ex * ex + ey * ey;
        m.blob = static_cast<int>(b);
        m.error_x_px = ex;
        m.error_y_px = ey;
      }
    }
    matches.push_back(m);
  }
  return matches;
}

void ErrorStats::add(double ex, double ey, double predicted_sigma, double crb_sigma) {
  ++n;
  sum_x += ex;
  sum_y += ey;
  sum_xx += ex * ex;
  sum_yy += ey * ey;
  sum_predicted_var += predicted_sigma * predicted_sigma;
  sum_crb_var += crb_sigma * crb_sigma;
}

double ErrorStats::rms() const {
  return n ? std::sqrt(0.5 * (sum_xx + sum_yy) / n) : 0;
}
double ErrorStats::rms_crb() const {
  return n ? std::sqrt(sum_crb_var / n) : 0;
}
double ErrorStats::rms_predicted() const {
  return n ? std::sqrt(sum_predicted_var / n) : 0;
}

}  // namespace storetrack::centroid::eval
