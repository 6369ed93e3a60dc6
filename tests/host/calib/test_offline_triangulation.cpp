// storetrack-calib triangulate (docs/calibration.md, "Triangulate") against simulator truth: the
// simulator's calibrated rig is the stated calibration (joint covariance); each trial draws the
// true rig from that covariance, projects a true mark through it with centroid noise, and
// triangulates the pixels with the stated rig. The NEES of the mark against its true position
// must be chi-square(3): mean and tail count inside derived bands. Bad input: each case with
// its message and exit code. STORETRACK_TRIANGULATE_WRITE_DIR=DIR writes a static record's
// files for the end-to-end test (storetrack-calib triangulate | storetrack-eval noise-floor).
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include <Eigen/Eigenvalues>

#include "perturbed_rig.hpp"
#include "storetrack/calib/calibration_comparison.hpp"
#include "storetrack/calib/offline_triangulation.hpp"
#include "storetrack/calib/point_uncertainty.hpp"
#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/json/text_file.hpp"
#include "storetrack/sim/simulator.hpp"
#include "storetrack/survey/survey.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"
#include "storetrack/uncertainty/statistics.hpp"
#include "triangulate_command.hpp"

namespace storetrack::calib {
namespace {

using geometry::Vec2;
using geometry::Vec3;

#ifdef STORETRACK_SANITIZE
constexpr int kTrials = 60;  // ~10x slower loops under ASan/UBSan
#else
constexpr int kTrials = 400;  // full form: STORETRACK_TRIANGULATE_TRIALS=N
#endif

int trials() {
  const char* env = std::getenv("STORETRACK_TRIANGULATE_TRIALS");
  return env ? std::atoi(env) : kTrials;
}

const camera::RigCalibration& stated_rig() {
  static const camera::RigCalibration rig = [] {
    const sim::Scenario s =
        sim::load_scenario(std::string(STORETRACK_SCENARIO_DIR) + "/store_separation.json");
    return sim::Simulator(s, 1).calibrated_rig();
  }();
  return rig;
}

/// Pixel observations of `points` (mark id = index) in every camera of `truth` that sees them,
/// with centroid noise sigma_px, one exposure.
std::vector<PixelObservation> observe(const camera::RigCalibration& truth,
                                      const std::vector<Vec3>& points, std::int64_t exposure,
                                      double sigma_px, std::mt19937_64& rng) {
  std::normal_distribution<double> noise(0, sigma_px);
  std::vector<PixelObservation> out;
  for (size_t i = 0; i < points.size(); ++i)
    for (const SlotPixel& p : visible_pixels(truth, points[i])) {
      PixelObservation o;
      o.exposure = exposure;
      o.time_ns = 1000000000LL + exposure * 10000000LL;
      o.camera_id = truth.cameras[static_cast<size_t>(p.slot)].camera_id;
      o.mark_id = static_cast<int>(i);
      o.pixel_px = p.pixel_px + Vec2(noise(rng), noise(rng));
      o.covariance_px = sigma_px * sigma_px * Eigen::Matrix2d::Identity();
      out.push_back(o);
    }
  return out;
}

std::vector<Vec3> points_in_volume(const camera::RigCalibration& rig, int n, std::mt19937_64& rng) {
  const WorkingVolume v = default_working_volume(rig, default_working_distances(rig, "rig"), "rig");
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<Vec3> out;
  while (static_cast<int>(out.size()) < n) {
    const Vec3 x = v.min_w + (v.max_w - v.min_w).cwiseProduct(Vec3(u(rng), u(rng), u(rng)));
    if (visible_pixels(rig, x).size() >= 2) out.push_back(x);
  }
  return out;
}

TEST(OfflineTriangulation, NeesOfMarksWithDrawnCalibrationIsChiSquare3) {
  const camera::RigCalibration& stated = stated_rig();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(stated.full_joint_covariance());
  const Eigen::MatrixXd L =
      eig.eigenvectors() * eig.eigenvalues().cwiseMax(0.0).cwiseSqrt().asDiagonal();
  std::mt19937_64 rng(28);
  std::normal_distribution<double> z(0, 1);
  const int n = trials();
  const double tail_quantile = uncertainty::chi_square_quantile(uncertainty::Probability(0.95),
                                                                uncertainty::DegreesOfFreedom(3));
  double nees_sum = 0, calibration_share = 0;
  int tail = 0;
  for (int t = 0; t < n; ++t) {
    Eigen::VectorXd e(L.cols());
    for (Eigen::Index i = 0; i < e.size(); ++i)
      e(i) = z(rng);
    const camera::RigCalibration truth = test::perturbed_rig(stated, L * e);
    const std::vector<Vec3> mark = points_in_volume(truth, 1, rng);
    const OfflineTriangulation r =
        triangulate_observations(stated, observe(truth, mark, t, 0.1, rng), "rig", "obs");
    ASSERT_EQ(r.marks.size(), 1u);
    const TriangulatedMark& m = r.marks[0];
    Eigen::Matrix3d W;
    ASSERT_TRUE(uncertainty::inverse_spd<3>(m.cov_w, W));
    const Vec3 d = m.p_w - mark[0];
    const double nees = d.dot(W * d);
    nees_sum += nees;
    tail += nees > tail_quantile ? 1 : 0;
    calibration_share += m.cov_calibration.trace() / m.cov_w.trace() / n;
  }
  // sum of n independent chi-square(3) ~ chi-square(3n); two-sided at total 1e-3.
  const double lo = uncertainty::chi_square_quantile(uncertainty::Probability(5e-4),
                                                     uncertainty::DegreesOfFreedom(3 * n)) /
                    n;
  const double hi = uncertainty::chi_square_quantile(uncertainty::Probability(1 - 5e-4),
                                                     uncertainty::DegreesOfFreedom(3 * n)) /
                    n;
  const uncertainty::CountInterval band = uncertainty::binomial_interval(n, 0.05, 5e-4);
  std::cout << "n = " << n << ": mean NEES " << nees_sum / n << " (band " << lo << " .. " << hi
            << "), NEES > chi2(3) 95 % quantile: " << tail << " (binomial band " << band.low
            << " .. " << band.high << "), calibration share of the variance " << calibration_share
            << "\n";
  EXPECT_GE(nees_sum / n, lo);
  EXPECT_LE(nees_sum / n, hi);
  EXPECT_GE(tail, band.low);
  EXPECT_LE(tail, band.high);
  EXPECT_GT(calibration_share, 0.05);  // the calibration term is really exercised
}

/// A moving mark: its pixels at three exposures 10 ms apart, each camera seeing it displaced by
/// v dt_c (dt_c: the camera's exposure-offset error, drawn once per trial).
std::vector<PixelObservation> observe_moving(const camera::RigCalibration& truth, const Vec3& p0,
                                             const Vec3& v, const std::vector<double>& dt_s,
                                             std::mt19937_64& rng) {
  std::normal_distribution<double> noise(0, 0.1);
  std::vector<PixelObservation> out;
  for (int k = 0; k < 3; ++k)
    for (size_t c = 0; c < truth.cameras.size(); ++c) {
      const auto& cam = truth.cameras[c];
      const Vec3 x = p0 + v * (0.01 * k + dt_s[c]);
      const auto u = cam.model.project_world(cam.T_c_w, x);
      const auto& in = cam.model.intrinsics();
      if (!u || u->x() < 0 || u->y() < 0 || u->x() > in.width - 1 || u->y() > in.height - 1)
        continue;
      PixelObservation o;
      o.exposure = k;
      o.time_ns = 10000000LL * k;
      o.camera_id = cam.camera_id;
      o.pixel_px = *u + Vec2(noise(rng), noise(rng));
      o.covariance_px = 0.01 * Eigen::Matrix2d::Identity();
      out.push_back(o);
    }
  return out;
}

TEST(OfflineTriangulation, NeesOfAMovingMarkWithSyncErrorsIsChiSquare3) {
  camera::RigCalibration stated = stated_rig();
  for (auto& cam : stated.cameras)
    cam.exposure_offset_sigma_ns = 2e6;  // 2 ms: 8 mm at 4 m/s
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(stated.full_joint_covariance());
  const Eigen::MatrixXd L =
      eig.eigenvectors() * eig.eigenvalues().cwiseMax(0.0).cwiseSqrt().asDiagonal();
  std::mt19937_64 rng(2028);
  std::normal_distribution<double> z(0, 1);
  const Vec3 v(4, 0, -0.5);
  const int n = trials();
  double nees_sum = 0, sync_share = 0, nees_without_sync = 0;
  for (int t = 0; t < n; ++t) {
    Eigen::VectorXd e(L.cols());
    for (Eigen::Index i = 0; i < e.size(); ++i)
      e(i) = z(rng);
    const camera::RigCalibration truth = test::perturbed_rig(stated, L * e);
    std::vector<double> dt_s;
    for (size_t c = 0; c < stated.cameras.size(); ++c)
      dt_s.push_back(2e-3 * z(rng));
    Vec3 p0 = points_in_volume(truth, 1, rng)[0];
    const auto seen_throughout = [&](const Vec3& p) {  // 2 exposures of margin either side
      for (int k = -2; k <= 4; ++k)
        if (visible_pixels(truth, p + 0.01 * k * v).size() < 2) return false;
      return true;
    };
    while (!seen_throughout(p0))
      p0 = points_in_volume(truth, 1, rng)[0];
    const OfflineTriangulation r =
        triangulate_observations(stated, observe_moving(truth, p0, v, dt_s, rng), "rig", "obs");
    const TriangulatedMark* middle = nullptr;
    for (const auto& m : r.marks)
      if (m.exposure == 1) middle = &m;
    ASSERT_NE(middle, nullptr) << r.marks.size() << " marks, " << r.single_camera_marks
                               << " single, " << r.failed_marks << " failed";
    ASSERT_TRUE(middle->velocity_w.has_value());
    Eigen::Matrix3d W;
    ASSERT_TRUE(uncertainty::inverse_spd<3>(middle->cov_w, W));
    const Vec3 d = middle->p_w - (p0 + 0.01 * v);
    nees_sum += d.dot(W * d);
    Eigen::Matrix3d W_without_sync;
    ASSERT_TRUE(uncertainty::inverse_spd<3>(middle->cov_w - middle->cov_sync, W_without_sync));
    nees_without_sync += d.dot(W_without_sync * d) / n;
    sync_share += middle->cov_sync.trace() / middle->cov_w.trace() / n;
  }
  const double lo = uncertainty::chi_square_quantile(uncertainty::Probability(5e-4),
                                                     uncertainty::DegreesOfFreedom(3 * n)) /
                    n;
  const double hi = uncertainty::chi_square_quantile(uncertainty::Probability(1 - 5e-4),
                                                     uncertainty::DegreesOfFreedom(3 * n)) /
                    n;
  std::cout << "moving mark, n = " << n << ": mean NEES " << nees_sum / n << " (band " << lo
            << " .. " << hi << "), without the sync term " << nees_without_sync
            << ", sync share of the variance " << sync_share << "\n";
  EXPECT_GE(nees_sum / n, lo);
  EXPECT_LE(nees_sum / n, hi);
  EXPECT_GT(sync_share, 0.2);        // the sync term is really exercised
  EXPECT_GT(nees_without_sync, hi);  // and needed
}

/// A scratch directory with the stated rig and a static record written to it.
struct Files {
  std::string dir, rig, observations, marks;
  explicit Files(const std::string& name) : dir(::testing::TempDir() + "/" + name) {
    std::filesystem::remove_all(dir);
    std::filesystem::create_directories(dir);
    rig = dir + "/rig.json";
    observations = dir + "/observations.csv";
    marks = dir + "/marks.csv";
    camera::write_rig_calibration(stated_rig(), rig);
  }
  void write(const std::string& path, const std::string& text) const {
    std::ofstream(path) << text;
  }
};

std::string csv_of(const std::vector<PixelObservation>& obs) {
  std::ostringstream s;
  s.precision(12);
  s << "exposure,time_ns [ns],camera_id,mark_id,u [px],v [px],sigma [px]\n";
  for (const PixelObservation& o : obs)
    s << o.exposure << ',' << *o.time_ns << ',' << o.camera_id << ',' << o.mark_id << ','
      << o.pixel_px.x() << ',' << o.pixel_px.y() << ',' << std::sqrt(o.covariance_px(0, 0)) << '\n';
  return s.str();
}

struct CommandRun {
  int rc = 0;
  std::string out, err;
};
CommandRun run(const Files& f) {
  calibapp::TriangulateArgs args;
  args.calibration = f.rig;
  args.observations = f.observations;
  args.output = f.marks;
  std::ostringstream out, err;
  CommandRun r;
  r.rc = calibapp::run_triangulate(args, out, err);
  r.out = out.str();
  r.err = err.str();
  return r;
}

TEST(OfflineTriangulation, WritesAStaticRecordForStoretrackEval) {
  const char* env = std::getenv("STORETRACK_TRIANGULATE_WRITE_DIR");
  const Files f("triangulate_record");
  const std::string dir = env ? env : f.dir;
  std::filesystem::create_directories(dir);
  std::mt19937_64 rng(7);
  const camera::RigCalibration& rig = stated_rig();
  const std::vector<Vec3> marks = points_in_volume(rig, 6, rng);
  std::vector<PixelObservation> obs;
  for (int exposure = 0; exposure < 12; ++exposure) {
    const auto one = observe(rig, marks, exposure, 0.1, rng);
    obs.insert(obs.end(), one.begin(), one.end());
  }
  survey::RigidBodySurvey reference;
  reference.name = "reference";
  reference.frame = 'w';
  reference.mark_diameter_m = 0.03;
  for (size_t i = 0; i < marks.size(); ++i)
    reference.marks.push_back({static_cast<int>(i), marks[i], 1e-4});
  camera::write_rig_calibration(rig, dir + "/rig.json");
  f.write(dir + "/observations.csv", csv_of(obs));
  survey::write_survey(reference, dir + "/survey.json");
  std::filesystem::remove(dir + "/marks.csv");
  calibapp::TriangulateArgs args{dir + "/rig.json", dir + "/observations.csv", dir + "/marks.csv",
                                 "p"};
  std::ostringstream out, err;
  ASSERT_EQ(calibapp::run_triangulate(args, out, err), 0) << err.str();
  EXPECT_NE(out.str().find("triangulate: 72 marks triangulated, 0 seen by one camera"),
            std::string::npos)
      << out.str();
  if (env) std::filesystem::remove(dir + "/marks.csv");  // the CLI test writes it again
}

TEST(OfflineTriangulation, CameraTheCalibrationLacksIsRefusedNamingLineAndCamera) {
  const Files f("triangulate_camera");
  f.write(f.observations,
          "exposure,camera_id,mark_id,u,v,sigma\n0,0,1,900,500,0.1\n0,9,1,910,505,0.1\n");
  const CommandRun r = run(f);
  EXPECT_EQ(r.rc, 2);
  EXPECT_NE(
      r.err.find(f.observations + ":3: camera_id: camera 9 is not in the calibration " + f.rig),
      std::string::npos)
      << r.err;
  EXPECT_FALSE(std::filesystem::exists(f.marks));
}

TEST(OfflineTriangulation, MalformedRowIsRefusedNamingLineAndField) {
  const Files f("triangulate_malformed");
  f.write(f.observations,
          "exposure,camera_id,mark_id,u,v,sigma\n0,0,1,900,500,0.1\n0,1,1,9x0,505,0.1\n");
  CommandRun r = run(f);
  EXPECT_EQ(r.rc, 2);
  EXPECT_NE(r.err.find(f.observations + ":3: u: expected a number, got '9x0'"), std::string::npos)
      << r.err;
  f.write(f.observations, "exposure,camera_id,mark_id,u,v,sigma\n0,0,1,900,500\n");
  r = run(f);
  EXPECT_EQ(r.rc, 2);
  EXPECT_NE(r.err.find(f.observations + ":2: row: 5 cells, the header needs 6"), std::string::npos)
      << r.err;
  f.write(f.observations, "exposure,camera_id,mark_id,u,v\n0,0,1,900,500\n");
  r = run(f);
  EXPECT_EQ(r.rc, 2);
  EXPECT_NE(r.err.find(f.observations + ":1: sigma: expected either a sigma column"),
            std::string::npos)
      << r.err;
  f.write(f.observations, "exposure,camera_id,mark_id,u,v,sigma\n0,0,1,900,500,-0.1\n");
  r = run(f);
  EXPECT_EQ(r.rc, 2);
  EXPECT_NE(r.err.find(f.observations + ":2: sigma: not > 0"), std::string::npos) << r.err;
  EXPECT_FALSE(std::filesystem::exists(f.marks));
}

TEST(OfflineTriangulation, MarkSeenByOneCameraIsCountedNotTriangulated) {
  const Files f("triangulate_single");
  std::mt19937_64 rng(3);
  const std::vector<Vec3> marks = points_in_volume(stated_rig(), 2, rng);
  std::vector<PixelObservation> obs = observe(stated_rig(), marks, 0, 0.1, rng);
  const int kept_camera = obs.back().camera_id;  // mark 1: one camera only
  std::erase_if(
      obs, [&](const PixelObservation& o) { return o.mark_id == 1 && o.camera_id != kept_camera; });
  f.write(f.observations, csv_of(obs));
  const CommandRun r = run(f);
  EXPECT_EQ(r.rc, 0) << r.err;
  EXPECT_NE(r.out.find("1 marks triangulated, 1 seen by one camera only"), std::string::npos)
      << r.out;
  EXPECT_NE(r.err.find("warning: 1 (exposure, mark) pairs are seen by one camera only"),
            std::string::npos)
      << r.err;
}

TEST(OfflineTriangulation, ExistingOutputIsRefusedNotOverwritten) {
  const Files f("triangulate_existing");
  std::mt19937_64 rng(5);
  f.write(f.observations,
          csv_of(observe(stated_rig(), points_in_volume(stated_rig(), 2, rng), 0, 0.1, rng)));
  f.write(f.marks, "keep me\n");
  const CommandRun r = run(f);
  EXPECT_EQ(r.rc, 2);
  EXPECT_NE(r.err.find(f.marks + ": exists; not overwritten"), std::string::npos) << r.err;
  EXPECT_EQ(jsonfile::read_text_file(f.marks), "keep me\n");
}

}  // namespace
}  // namespace storetrack::calib
