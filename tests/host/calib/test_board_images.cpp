// Rendered calibration-board images with known truth (common/sim board_render.hpp) through the
// project's chessboard detection and rig calibration:
//  - a noise-free render's detected corners lie within a stated bound of the true projections;
//  - Monte Carlo of the rig calibration's covariance (issue 9, "Honest covariance"): fresh sensor
//    noise on the same rendered boards, detect -> rig bundle adjustment, and the errors against
//    the true rig must match the stated joint covariance (per parameter, per principal direction
//    and pooled NEES); wrong covariances (scaled, cross terms dropped) must fail the same tests.
// STORETRACK_CALIB_MC_DRAWS=N sets the number of recalibrations (docs/calibration.md).
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "storetrack/calib/chessboard_detection.hpp"
#include "storetrack/calib/rig_calibration.hpp"
#include "storetrack/sim/board_set.hpp"
#include "storetrack/sim/scenario.hpp"
#include "storetrack/sim/simulator.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::calib {
namespace {

using uncertainty::chi_square_quantile;
using uncertainty::DegreesOfFreedom;
using uncertainty::Probability;

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// The static scenario's true rig, first two cameras (camera 0 = reference).
camera::RigCalibration scenario_rig() {
  sim::Scenario sc = sim::load_scenario(std::string(STORETRACK_SIM_SCENARIO_DIR) + "/static.json");
  sc.cameras.resize(2);
  return sim::Simulator(sc, 1).true_rig();
}

sim::BoardPhotometry scenario_photometry() {
  const sim::Scenario sc =
      sim::load_scenario(std::string(STORETRACK_SIM_SCENARIO_DIR) + "/static.json");
  sim::BoardPhotometry ph;
  ph.sensor = sc.optics.sensor;
  ph.psf_sigma_px = sc.optics.psf_sigma_px;
  return ph;
}

ChessboardSpec spec_of(const sim::ChessboardTarget& board) {
  ChessboardSpec spec;
  spec.cols = board.cols;
  spec.rows = board.rows;
  spec.square_m = board.square_m;
  return spec;
}

// One camera's view of one frame: its clean render, rendered once.
struct View {
  int frame = 0;
  std::size_t camera_index = 0;
  sim::BoardExpectedImage expected;
};

std::vector<View> render_views(const camera::RigCalibration& rig,
                               const std::vector<sim::BoardFrame>& frames,
                               const sim::BoardSetOptions& options,
                               const sim::BoardPhotometry& photometry) {
  std::vector<View> views;
  for (const sim::BoardFrame& f : frames) {
    for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
      const int id = rig.cameras[c].camera_id;
      if (std::find(f.cameras_seeing.begin(), f.cameras_seeing.end(), id) == f.cameras_seeing.end())
        continue;
      View v;
      v.frame = f.frame;
      v.camera_index = c;
      sim::render_board_expected(rig.cameras[c].model, sim::board_in_camera(rig.cameras[c], f),
                                 options.board, photometry, v.expected);
      views.push_back(std::move(v));
    }
  }
  return views;
}

TEST(BoardImages, NoiseFreeRenderDetectsAtTheTrueCorners) {
  const camera::RigCalibration rig = scenario_rig();
  sim::BoardSetOptions options;
  options.common_views = 3;
  options.single_views = 3;
  const auto frames = sim::plan_board_frames(rig, options, 11);
  const sim::BoardPhotometry photometry = scenario_photometry();
  auto t0 = std::chrono::steady_clock::now();
  const std::vector<View> views = render_views(rig, frames, options, photometry);
  const double render_ms = 1e3 * seconds_since(t0) / static_cast<double>(views.size());
  double sum2 = 0, worst = 0;
  int n = 0, found = 0;
  std::vector<std::uint8_t> gray;
  t0 = std::chrono::steady_clock::now();
  for (const View& v : views) {
    const camera::CalibratedCamera& cam = rig.cameras[v.camera_index];
    gray.resize(v.expected.electrons.size());
    sim::expose_noise_free(v.expected.electrons.data(), v.expected.width, photometry.sensor,
                           gray.data(), v.expected.width, v.expected.height, v.expected.width);
    ObservationSet set;
    if (!detect_chessboard_image(gray.data(), v.expected.width, v.expected.height, v.expected.width,
                                 spec_of(options.board), cam.camera_id, v.frame, set))
      continue;
    ++found;
    const auto truth = sim::project_board_corners(
        cam.model, sim::board_in_camera(cam, frames[static_cast<std::size_t>(v.frame)]),
        options.board);
    for (const Observation& o : set.observations) {
      const double e = (o.pixel - *truth[static_cast<std::size_t>(o.point_id)]).norm();
      sum2 += e * e;
      worst = std::max(worst, e);
      ++n;
    }
  }
  const double detect_ms = 1e3 * seconds_since(t0) / static_cast<double>(views.size());
  std::printf(
      "noise-free: %d of %zu views detected, %d corners, rms %.4f px, max %.4f px; "
      "render %.0f ms, detect %.0f ms per image\n",
      found, views.size(), n, std::sqrt(sum2 / std::max(n, 1)), worst, render_ms, detect_ms);
  EXPECT_EQ(found, static_cast<int>(views.size()));
  // Bound: the renderer's own corner error is < 0.002 px (the bilinear board map; exact area
  // coverage otherwise); what remains is the detector's: cornerSubPix's 23 x 23 px window on
  // an 8-bit quantised image, with distortion-curved edges and, for squares of 14-40 px, the
  // neighbouring corners inside the window. Measured (seed 11, 13 views, 910 corners): rms
  // 0.022 px, max 0.054 px; bound rms 0.03, max 0.08 px, several times below the corner noise
  // of the noisy images (the rig fit's residual sigma, Monte Carlo below).
  EXPECT_LT(std::sqrt(sum2 / std::max(n, 1)), 0.03);
  EXPECT_LT(worst, 0.08);
}

// The estimated parameters of the 2-camera rig: each camera's free intrinsics (default model:
// fx, fy, cx, cy, k1, k2, p1, p2, k3) and camera 1's T_c_r; indices into the joint covariance.
struct Parameters {
  std::vector<int> joint_index;
  std::vector<std::string> names;
};

Parameters rig_parameters() {
  Parameters p;
  const int intrinsics[] = {0, 1, 2, 3, 5, 6, 7, 8, 9};
  const char* intrinsic_names[] = {"fx", "fy", "cx", "cy", "skew", "k1", "k2",
                                   "p1", "p2", "k3", "k4", "k5",   "k6"};
  const char* pose_names[] = {"rx", "ry", "rz", "tx", "ty", "tz"};
  for (int c = 0; c < 2; ++c) {
    for (int i : intrinsics) {
      p.joint_index.push_back(c * kRigBlockSize + i);
      p.names.push_back("cam" + std::to_string(c) + "." + intrinsic_names[i]);
    }
  }
  for (int i = 0; i < 6; ++i) {
    p.joint_index.push_back(kRigBlockSize + camera::kNumIntrinsics + i);
    p.names.push_back(std::string("cam1.") + pose_names[i]);
  }
  return p;
}

// One recalibration: the error against the truth and the stated covariance of the parameters.
struct Draw {
  Eigen::VectorXd error;
  Eigen::MatrixXd covariance;
  double residual_sigma_px = 0;  // the fit's, which scales the covariance
  // Diagnostics of the detected corners against the true projections: per-axis rms, the
  // correlation of x with y, and of neighbouring corners' x errors along a row.
  double corner_sigma_px = 0, corner_xy_correlation = 0, neighbour_correlation = 0;
};

void corner_diagnostics(const camera::RigCalibration& rig, const std::vector<View>& views,
                        const std::vector<sim::BoardFrame>& frames,
                        const sim::BoardSetOptions& options, const ObservationSet& set, Draw& d) {
  std::map<std::pair<int, int>, std::map<int, Eigen::Vector2d>> errors;  // (camera, frame)
  for (const Observation& o : set.observations) {
    const auto& cam = *rig.find(o.camera);
    const auto truth = sim::project_board_corners(
        cam.model, sim::board_in_camera(cam, frames[static_cast<std::size_t>(o.frame)]),
        options.board);
    errors[{o.camera, o.frame}][o.point_id] =
        o.pixel - *truth[static_cast<std::size_t>(o.point_id)];
  }
  (void)views;
  double sxx = 0, syy = 0, sxy = 0, snn = 0, sn = 0;
  int n = 0, nn = 0;
  for (const auto& [key, view] : errors) {
    for (const auto& [id, e] : view) {
      sxx += e.x() * e.x();
      syy += e.y() * e.y();
      sxy += e.x() * e.y();
      ++n;
      const auto next = view.find(id + 1);
      if ((id + 1) % options.board.cols != 0 && next != view.end()) {
        snn += e.x() * next->second.x();
        sn += e.x() * e.x();
        ++nn;
      }
    }
  }
  d.corner_sigma_px = std::sqrt((sxx + syy) / (2.0 * std::max(n, 1)));
  d.corner_xy_correlation = sxy / std::sqrt(sxx * syy);
  d.neighbour_correlation = nn > 0 ? snn / sn : 0;
}

Draw recalibrate(const camera::RigCalibration& rig, const std::vector<View>& views,
                 const std::vector<sim::BoardFrame>& frames, const sim::BoardSetOptions& options,
                 const sim::BoardPhotometry& photometry, const Parameters& params,
                 std::uint64_t seed) {
  ObservationSet set;
  std::vector<std::uint8_t> gray;
  for (const View& v : views) {
    const camera::CalibratedCamera& cam = rig.cameras[v.camera_index];
    gray.resize(v.expected.electrons.size());
    std::mt19937_64 rng(sim::board_image_seed(seed, v.frame, cam.camera_id));
    sim::expose(v.expected.electrons.data(), v.expected.width, photometry.sensor, rng, gray.data(),
                v.expected.width, v.expected.height, v.expected.width);
    detect_chessboard_image(gray.data(), v.expected.width, v.expected.height, v.expected.width,
                            spec_of(options.board), cam.camera_id, v.frame, set);
  }
  const RigResult result = calibrate_rig(set, RigOptions{});
  Eigen::VectorXd full = Eigen::VectorXd::Zero(2 * kRigBlockSize);
  for (int c = 0; c < 2; ++c) {
    full.segment<camera::kNumIntrinsics>(c * kRigBlockSize) =
        camera::pack(result.cameras[static_cast<std::size_t>(c)].intrinsics) -
        camera::pack(rig.cameras[static_cast<std::size_t>(c)].model.intrinsics());
  }
  const geometry::Transform T_c1_r_true = rig.cameras[1].T_c_w * rig.cameras[0].T_c_w.inverse();
  full.segment<6>(kRigBlockSize + camera::kNumIntrinsics) =
      geometry::left_difference(result.cameras[1].T_c_r, T_c1_r_true);
  const auto n = static_cast<Eigen::Index>(params.joint_index.size());
  Draw d;
  d.residual_sigma_px = result.residual_sigma_px;
  corner_diagnostics(rig, views, frames, options, set, d);
  d.error.resize(n);
  d.covariance.resize(n, n);
  for (Eigen::Index i = 0; i < n; ++i) {
    d.error[i] = full[params.joint_index[static_cast<std::size_t>(i)]];
    for (Eigen::Index j = 0; j < n; ++j) {
      d.covariance(i, j) = result.joint_covariance(params.joint_index[static_cast<std::size_t>(i)],
                                                   params.joint_index[static_cast<std::size_t>(j)]);
    }
  }
  return d;
}

// The honesty statistics of a set of draws against a covariance model `model` (the stated
// covariance, or a deliberately wrong one).
struct Honesty {
  Eigen::VectorXd parameter_ratio;  // sqrt(mean (e_j / sigma_j)^2), per parameter
  Eigen::VectorXd direction_ratio;  // the same along the principal directions of the correlation
  double mean_nees = 0;
};

Honesty honesty(const std::vector<Draw>& draws,
                const std::function<Eigen::MatrixXd(const Eigen::MatrixXd&)>& model) {
  const Eigen::Index n = draws.front().error.size();
  // Directions: eigenvectors of the mean stated correlation (units differ between parameters),
  // a_k = S^-1 u_k; the smallest-eigenvalue ones are where cross terms matter most.
  Eigen::MatrixXd mean = Eigen::MatrixXd::Zero(n, n);
  for (const Draw& d : draws)
    mean += d.covariance / static_cast<double>(draws.size());
  const Eigen::VectorXd s_inv = mean.diagonal().cwiseSqrt().cwiseInverse();
  const Eigen::MatrixXd correlation = s_inv.asDiagonal() * mean * s_inv.asDiagonal();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(correlation);
  const Eigen::MatrixXd A = s_inv.asDiagonal() * eig.eigenvectors();
  Honesty h;
  h.parameter_ratio = Eigen::VectorXd::Zero(n);
  h.direction_ratio = Eigen::VectorXd::Zero(n);
  for (const Draw& d : draws) {
    const Eigen::MatrixXd C = model(d.covariance);
    h.parameter_ratio += d.error.cwiseAbs2().cwiseQuotient(C.diagonal());
    const Eigen::VectorXd projected = A.transpose() * d.error;
    h.direction_ratio += projected.cwiseAbs2().cwiseQuotient((A.transpose() * C * A).diagonal());
    h.mean_nees += d.error.dot(C.ldlt().solve(d.error));
  }
  const double m = static_cast<double>(draws.size());
  h.parameter_ratio = (h.parameter_ratio / m).cwiseSqrt();
  h.direction_ratio = (h.direction_ratio / m).cwiseSqrt();
  h.mean_nees /= m;
  return h;
}

// Acceptance bands for m draws of a d-parameter covariance. A ratio r of one parameter:
// m r^2 ~ chi-square(m) when the covariance is right; 2d ratios (parameters + directions),
// Bonferroni at a family false-alarm rate of 1 %. The pooled NEES: m mean ~ chi-square(m d),
// two-sided 99.9 %.
struct Bands {
  double ratio_low, ratio_high, nees_low, nees_high;
};

Bands bands(int m, int d) {
  const double alpha = 0.01 / (2.0 * d);
  Bands b{};
  b.ratio_low = std::sqrt(chi_square_quantile(Probability(alpha / 2), DegreesOfFreedom(m)) / m);
  b.ratio_high =
      std::sqrt(chi_square_quantile(Probability(1 - alpha / 2), DegreesOfFreedom(m)) / m);
  b.nees_low = chi_square_quantile(Probability(0.0005), DegreesOfFreedom(m * d)) / m;
  b.nees_high = chi_square_quantile(Probability(0.9995), DegreesOfFreedom(m * d)) / m;
  return b;
}

// Number of failed tests (parameters and directions outside the band, NEES outside).
int failures(const Honesty& h, const Bands& b) {
  int n = 0;
  for (Eigen::Index i = 0; i < h.parameter_ratio.size(); ++i) {
    n += (h.parameter_ratio[i] < b.ratio_low || h.parameter_ratio[i] > b.ratio_high) ? 1 : 0;
    n += (h.direction_ratio[i] < b.ratio_low || h.direction_ratio[i] > b.ratio_high) ? 1 : 0;
  }
  n += (h.mean_nees < b.nees_low || h.mean_nees > b.nees_high) ? 1 : 0;
  return n;
}

#ifdef STORETRACK_SANITIZE
constexpr int kDefaultDraws = 4;  // ASan/UBSan at -O1: the chain under the sanitizers, wider bands
#else
constexpr int kDefaultDraws = 20;
#endif
// Below 8 draws the bands are too wide to reject the wrong covariances (power, not honesty):
// the sanitizer form names them but does not require it.
constexpr int kMinDrawsToRejectWrong = 8;

int draws_from_env(int fallback) {
  const char* env = std::getenv("STORETRACK_CALIB_MC_DRAWS");
  return env != nullptr ? std::max(3, std::atoi(env)) : fallback;
}

TEST(BoardImages, RigCovarianceIsHonestOnRenderedBoards) {
  const camera::RigCalibration rig = scenario_rig();
  sim::BoardSetOptions options;
  options.common_views = 5;
  options.single_views = 5;
  const sim::BoardPhotometry photometry = scenario_photometry();
  const Parameters params = rig_parameters();
  const int m = draws_from_env(kDefaultDraws);
  std::vector<Draw> draws;
  std::size_t images = 0;
  const auto t0 = std::chrono::steady_clock::now();
  // Each draw a fresh board set (poses) and fresh sensor noise: the detector's own corner bias
  // (0.016 px per axis on a noise-free render, as large as this sensor's corner noise) is a
  // fixed pattern for fixed poses, so with the poses held fixed the parameters' errors carried a
  // fixed offset of up to 1.1 sigma (40 draws) and the test measured that pattern, not the
  // covariance. A real calibration's poses are new every time, as here.
  for (int k = 0; k < m; ++k) {
    const auto frames = sim::plan_board_frames(rig, options, 21 + static_cast<std::uint64_t>(k));
    const std::vector<View> views = render_views(rig, frames, options, photometry);
    images += views.size();
    draws.push_back(recalibrate(rig, views, frames, options, photometry, params, 1000 + k));
  }
  const double per_draw_s = seconds_since(t0) / m;
  const int d = static_cast<int>(params.joint_index.size());
  const Bands b = bands(m, d);
  const auto stated = [](const Eigen::MatrixXd& C) { return C; };
  const Honesty h = honesty(draws, stated);
  std::printf("%d recalibrations (%zu images, %.1f s per draw), %d parameters\n", m, images,
              per_draw_s, d);
  std::printf("bands: ratio [%.3f, %.3f], mean NEES [%.2f, %.2f] (dimension %d)\n", b.ratio_low,
              b.ratio_high, b.nees_low, b.nees_high, d);
  for (int i = 0; i < d; ++i) {
    std::printf("  %-9s spread/sigma %.3f   direction %2d %.3f\n",
                params.names[static_cast<std::size_t>(i)].c_str(), h.parameter_ratio[i], i,
                h.direction_ratio[i]);
  }
  std::printf("mean NEES %.2f (dimension %d)\n", h.mean_nees, d);
  Eigen::VectorXd bias = Eigen::VectorXd::Zero(d);
  double fit_sigma = 0, corner_sigma = 0, xy = 0, neighbour = 0;
  for (const Draw& dr : draws) {
    bias += dr.error.cwiseQuotient(dr.covariance.diagonal().cwiseSqrt()) / m;
    fit_sigma += dr.residual_sigma_px / m;
    corner_sigma += dr.corner_sigma_px / m;
    xy += dr.corner_xy_correlation / m;
    neighbour += dr.neighbour_correlation / m;
  }
  std::printf("mean error / sigma (bias; +-%.2f is 2 standard errors):", 2 / std::sqrt(m));
  for (int i = 0; i < d; ++i)
    std::printf(" %.2f", bias[i]);
  std::printf(
      "\ncorners: fit residual sigma %.4f px, detected - true %.4f px per axis, "
      "x-y correlation %.3f, neighbour correlation %.3f\n",
      fit_sigma, corner_sigma, xy, neighbour);
  EXPECT_EQ(failures(h, b), 0);

  // Wrong covariances on the same draws must fail.
  // covariance x 1.4 moves the mean NEES by -29 %; the measured NEES sits ~10 % above d (see
  // docs/calibration.md), so it leaves the 99.9 % band only from about 40 draws (m = 20: NEES
  // 19.4 against a lower bound of 19.2); the reduced form names it but does not require it.
  struct Wrong {
    const char* name;
    std::function<Eigen::MatrixXd(const Eigen::MatrixXd&)> model;
    int min_draws = kMinDrawsToRejectWrong;
  };
  const std::vector<Wrong> wrong = {
      {"covariance x 0.7",
       [](const Eigen::MatrixXd& C) {
         Eigen::MatrixXd W = 0.7 * C;
         return W;
       }},
      {"covariance x 1.4",
       [](const Eigen::MatrixXd& C) {
         Eigen::MatrixXd W = 1.4 * C;
         return W;
       },
       40},
      {"sigma x 0.7",
       [](const Eigen::MatrixXd& C) {
         Eigen::MatrixXd W = 0.49 * C;
         return W;
       }},
      {"sigma x 1.4",
       [](const Eigen::MatrixXd& C) {
         Eigen::MatrixXd W = 1.96 * C;
         return W;
       }},
      {"cross terms dropped (diagonal)",
       [](const Eigen::MatrixXd& C) {
         Eigen::MatrixXd W = C.diagonal().asDiagonal();
         return W;
       }},
  };
  for (const Wrong& w : wrong) {
    const Honesty hw = honesty(draws, w.model);
    const int f = failures(hw, b);
    std::printf(
        "%-32s mean NEES %.2f, worst parameter ratio %.3f / %.3f, directions %.3f / "
        "%.3f: %d tests fail\n",
        w.name, hw.mean_nees, hw.parameter_ratio.minCoeff(), hw.parameter_ratio.maxCoeff(),
        hw.direction_ratio.minCoeff(), hw.direction_ratio.maxCoeff(), f);
    if (m >= w.min_draws) {
      EXPECT_GT(f, 0) << w.name;
    } else {
      std::printf("  (%s: not required to fail with %d < %d draws)\n", w.name, m, w.min_draws);
    }
  }
}

}  // namespace
}  // namespace storetrack::calib
