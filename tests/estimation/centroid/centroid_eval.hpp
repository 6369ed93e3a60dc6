// Truth-side helpers shared by the centroid tests and storetrack-centroid-bench: the Cramer-Rao
// bound of a spot (Fisher information from the simulator's noise-free expected image), random
// mark layouts and detection-to-truth matching. Not part of the firmware.
#pragma once

#include <cstdint>
#include <random>
#include <span>
#include <vector>

#include "storetrack/centroid/centroider.hpp"
#include "storetrack/sim/render.hpp"

namespace storetrack::centroid::eval {

struct CramerRao {
  double sigma_x_px = 0, sigma_y_px = 0;
  double sigma_px = 0;  ///< sqrt((sx^2 + sy^2) / 2), comparable with Blob::sigma_px
};

/// Cramer-Rao bound of (x, y) with the flux as a nuisance parameter (background known: it is
/// estimated from thousands of pixels). Fisher information F = sum_i J_i J_i^T / var_i over the
/// spot's pixels, J_i = d mu_i / d(x, y, flux) by central differences of the simulator's
/// expected signal, var_i = background + mu_i + read^2 + gain^2 / 12 [e^2] (Poisson + Gaussian
/// read + quantisation, the Poisson-plus-Gaussian approximation of var = mean + read^2).
CramerRao cramer_rao(sim::SpotRenderer& renderer, const sim::Spot& spot,
                     const sim::SensorModel& sensor, int width, int height);

/// `count` spots copied from `prototype`, at uniform random sub-pixel positions on a jittered
/// grid (centres at least `margin` px from the border, cells of at least `min_spacing` px).
std::vector<sim::Spot> random_spots(const sim::Spot& prototype, int count, int width, int height,
                                    double margin, double min_spacing, std::mt19937_64& rng);

struct Match {
  int truth = -1;  ///< index into the truth spots
  int blob = -1;   ///< index into the blobs, -1: missed
  double error_x_px = 0, error_y_px = 0;
};

/// Nearest blob within `radius_px` of each truth spot.
std::vector<Match> match(std::span<const sim::Spot> truth, std::span<const Blob> blobs,
                         double radius_px);

/// Running error statistics against truth.
struct ErrorStats {
  int n = 0;
  int missed = 0;
  double sum_x = 0, sum_y = 0, sum_xx = 0, sum_yy = 0;
  double sum_predicted_var = 0;  ///< sum of sigma_px^2 reported by the centroider
  double sum_crb_var = 0;        ///< sum of the Cramer-Rao bound variances (per axis)
  void add(double ex, double ey, double predicted_sigma, double crb_sigma);
  double bias_x() const { return n ? sum_x / n : 0; }
  double bias_y() const { return n ? sum_y / n : 0; }
  double rms() const;      ///< per-axis RMS error about truth
  double rms_crb() const;  ///< per-axis RMS of the bound
  double rms_predicted() const;
  double ratio_to_crb() const { return rms() / rms_crb(); }
};

}  // namespace storetrack::centroid::eval
