// storetrack-calib compare / uncertainty-map against truth (docs/calibration.md, "Compare",
// "Uncertainty map"): the simulator's true rig and calibrated rigs drawn from their stated
// covariance, closed forms (a rigid motion, a scaled rig), and a Monte Carlo of triangulations
// with sampled calibration and centroid noise. STORETRACK_COMPARE_DRAWS=N for more draws.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include <Eigen/Eigenvalues>
#include <nlohmann/json.hpp>

#include "compare_command.hpp"
#include "perturbed_rig.hpp"
#include "storetrack/calib/calibration_comparison.hpp"
#include "storetrack/calib/point_uncertainty.hpp"
#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/sim/simulator.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "storetrack/uncertainty/statistics.hpp"

namespace storetrack::calib {
namespace {

using geometry::Mat3;
using geometry::Transform;
using geometry::Vec2;
using geometry::Vec3;

int draws(int ci_default) {
  const char* env = std::getenv("STORETRACK_COMPARE_DRAWS");
  return env ? std::atoi(env) : ci_default;
}

const sim::Scenario& scenario() {
  static const sim::Scenario s =
      sim::load_scenario(std::string(STORETRACK_SCENARIO_DIR) + "/store_separation.json");
  return s;
}

/// Two-sided interval of a chi-square(dof) sum at total false-alarm `alpha`.
std::pair<double, double> chi2_interval(int dof, double alpha = 1e-3) {
  using uncertainty::DegreesOfFreedom;
  using uncertainty::Probability;
  return {uncertainty::chi_square_quantile(Probability(alpha / 2), DegreesOfFreedom(dof)),
          uncertainty::chi_square_quantile(Probability(1 - alpha / 2), DegreesOfFreedom(dof))};
}

CompareOptions small_options() {
  CompareOptions o;
  o.volume_points = {7, 7, 7};
  o.grid_columns = 12;
  o.grid_rows = 7;
  return o;
}

/// Triangulation of the true rig's pixels of x through `rig` by the host's triangulate (the
/// independent route: no calib code).
std::optional<Vec3> triangulate_truth_pixels(const camera::RigCalibration& truth,
                                             const camera::RigCalibration& rig, const Vec3& x) {
  std::vector<triangulate::Observation> obs;
  for (size_t s = 0; s < truth.cameras.size(); ++s) {
    const auto& ct = truth.cameras[s];
    const auto u = ct.model.project_world(ct.T_c_w, x);
    const auto& in = ct.model.intrinsics();
    if (!u || u->x() < -0.5 || u->y() < -0.5 || u->x() >= in.width - 0.5 ||
        u->y() >= in.height - 0.5)
      continue;
    triangulate::Observation o;
    o.model = &rig.cameras[s].model;
    o.T_c_w = rig.cameras[s].T_c_w;
    o.pixel_px = *u;
    obs.push_back(o);
  }
  triangulate::Result r;
  if (obs.size() < 2 || !triangulate::triangulate(obs, triangulate::Options{}, r))
    return std::nullopt;
  return r.p_w;
}

Eigen::MatrixXd sampling_factor(const Eigen::MatrixXd& S) {
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(S);
  return eig.eigenvectors() * eig.eigenvalues().cwiseMax(0.0).cwiseSqrt().asDiagonal();
}

TEST(CompareCalibrations, FileWithItselfIsZero) {
  const camera::RigCalibration a = sim::Simulator(scenario(), 1).calibrated_rig();
  const ComparisonResult r = compare_calibrations(a, a, small_options());
  for (const auto& c : r.cameras) {
    EXPECT_LT(c.fitted.max, 2e-6) << "camera " << c.camera_id;  // unproject tolerance 1e-6 px
    EXPECT_LT(c.unfitted.max, 2e-6) << "camera " << c.camera_id;
    EXPECT_GT(c.fitted.count, 0);
  }
  EXPECT_GT(r.valid_points, 50);
  EXPECT_EQ(r.difference_m.max, 0.0);
  EXPECT_EQ(r.joint_chi2, 0.0);
  EXPECT_TRUE(r.consistent);
  EXPECT_EQ(r.better, '=');
  EXPECT_LT(geometry::left_difference(r.T_b_a, Transform::Identity()).norm(), 1e-9);
}

TEST(CompareCalibrations, RigidMotionOfTheWholeRigIsFittedOut) {
  const camera::RigCalibration a = sim::Simulator(scenario(), 1).calibrated_rig();
  // b: the same rig in a world moved by M (x_b = M x_a): T_c_wb = T_c_wa M^-1.
  Transform M = Transform::Identity();
  M.linear() = geometry::rotation_from_rotvec(Vec3(0.004, -0.007, 0.003));
  M.translation() = Vec3(0.012, -0.020, 0.008);
  camera::RigCalibration b = a;
  for (auto& c : b.cameras)
    c.T_c_w = c.T_c_w * M.inverse();
  const ComparisonResult r = compare_calibrations(a, b, small_options());
  for (const auto& c : r.cameras) {
    EXPECT_LT(c.fitted.max, 1e-5) << "camera " << c.camera_id;
    EXPECT_GT(c.unfitted.rms, 1.0) << "camera " << c.camera_id;  // the motion itself is visible
  }
  EXPECT_LT(geometry::left_difference(r.T_b_a, M).norm(), 1e-9);
  // The triangulated positions move with the world: a registration change, which the stated
  // covariances (a few mm) do not allow: do not fly.
  EXPECT_GT(r.difference_m.p50, 0.015);
  EXPECT_FALSE(r.consistent);
}

TEST(CompareCalibrations, SimulatorPairMatchesDirectTriangulationWithTheTrueRig) {
  const sim::Simulator s1(scenario(), 1), s2(scenario(), 2);
  const camera::RigCalibration truth = s1.true_rig(), a = s1.calibrated_rig(),
                               b = s2.calibrated_rig();
  const ComparisonResult r = compare_calibrations(a, b, small_options());
  int compared = 0, left_out = 0;
  double worst = 0;
  for (const auto& p : r.points) {
    if (!p.valid) continue;
    const auto pa = triangulate_truth_pixels(truth, a, p.p_w);
    const auto pb = triangulate_truth_pixels(truth, b, p.p_w);
    // The tool uses a's pixels (p.cameras of them); the truth may see another camera set at
    // the image border: those points are counted, not compared.
    if (!pa || !pb || static_cast<int>(visible_pixels(truth, p.p_w).size()) != p.cameras) {
      ++left_out;
      continue;
    }
    const Vec3 known = *pb - *pa;  // e_b - e_a: the two calibrations' known errors
    // Second order: the pixels differ from the true ones by a's error (~0.5 px), which changes
    // the difference by (d gain) x (pixel error): well below 5 % of it plus 20 um.
    const double off = (p.difference_m - known).norm();
    EXPECT_LT(off, 0.05 * known.norm() + 2e-5) << p.p_w.transpose();
    worst = std::max(worst, off / (known.norm() + 1e-9));
    ++compared;
  }
  EXPECT_GT(compared, 100);
  std::cout << "compared " << compared << " points (left out at the border " << left_out
            << "), worst relative offset " << worst << "\n";
}

TEST(CompareCalibrations, PairsDrawnFromTheirCovarianceAreConsistent) {
  // Simulator calibrations are truth + N(0, stated covariance): the difference at a point must
  // be N(0, S_a + S_b). n pairs, 3 points (2, 3 and 4 cameras): each point's chi-square sum in
  // the two-sided 99.9 % interval of chi-square(3n); the joint test refuses a pair with
  // probability <= 1 %: count <= the 99.95 % binomial bound.
#ifdef STORETRACK_SANITIZE
  const int n = draws(5);  // the chain under ASan/UBSan; the bands follow n
#else
  const int n = draws(30);
#endif
  const camera::RigCalibration a0 = sim::Simulator(scenario(), 1).calibrated_rig();
  UncertaintyMapOptions mo;
  mo.volume_points = {7, 7, 7};
  const UncertaintyMap map = uncertainty_map(a0, mo);
  std::vector<Vec3> points;
  for (int k = 2; k <= 4; ++k)
    for (const auto& p : map.points)
      if (p.valid && p.cameras == k) {
        points.push_back(p.p_w);
        break;
      }
  ASSERT_EQ(points.size(), 3u);
  std::vector<double> chi2(points.size(), 0.0);
  int refused = 0;
  for (int i = 0; i < n; ++i) {
    const camera::RigCalibration a = sim::Simulator(scenario(), 100 + 2 * i).calibrated_rig();
    const camera::RigCalibration b = sim::Simulator(scenario(), 101 + 2 * i).calibrated_rig();
    CompareOptions o = small_options();
    o.volume_points = {5, 5, 5};
    const ComparisonResult whole = compare_calibrations(a, b, o);
    refused += whole.consistent ? 0 : 1;
    for (size_t k = 0; k < points.size(); ++k) {
      o.volume = WorkingVolume{points[k], points[k]};
      o.volume_points = {1, 1, 1};
      const ComparisonResult r = compare_calibrations(a, b, o);
      ASSERT_TRUE(r.points[0].valid);
      chi2[k] += r.points[0].chi2;
    }
  }
  const auto [lo, hi] = chi2_interval(3 * n);
  for (size_t k = 0; k < points.size(); ++k) {
    std::cout << "point " << k << " (" << k + 2 << " cameras): mean chi2 " << chi2[k] / n
              << " (3), interval " << lo / n << ".." << hi / n << "\n";
    EXPECT_GT(chi2[k], lo);
    EXPECT_LT(chi2[k], hi);
  }
  const auto bound = uncertainty::binomial_interval(n, 0.01, 5e-4).high;
  std::cout << "joint test refused " << refused << " of " << n << " pairs (bound " << bound
            << ")\n";
  EXPECT_LE(refused, bound);
}

/// The rig with a correlated (cross-camera) part added to its covariance, as a world
/// registration leaves it: the same extrinsic error direction in every camera.
camera::RigCalibration with_cross_covariance(camera::RigCalibration rig) {
  const int n = static_cast<int>(rig.cameras.size());
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero(camera::kJointBlockSize * n, 6);
  for (int c = 0; c < n; ++c) {
    const int row = camera::kJointBlockSize * c + camera::kNumIntrinsics;
    B.block<3, 3>(row, 0) = Mat3::Identity() * 2e-4;      // rad
    B.block<3, 3>(row + 3, 3) = Mat3::Identity() * 1e-3;  // m
  }
  camera::set_joint_covariance(rig, rig.full_joint_covariance() + B * B.transpose());
  return rig;
}

/// NEES sums of triangulations with sampled calibration (from `sampled`) and centroid noise,
/// scored against the map's prediction from `stated` at each point.
std::vector<double> monte_carlo_nees(const camera::RigCalibration& sampled,
                                     const camera::RigCalibration& stated,
                                     const std::vector<Vec3>& points, double sigma_px, int n) {
  UncertaintyMapOptions mo;
  mo.sigma_px = sigma_px;
  mo.volume_points = {1, 1, 1};
  const Eigen::MatrixXd F = sampling_factor(sampled.full_joint_covariance());
  std::mt19937_64 rng(7);
  std::normal_distribution<double> normal;
  std::vector<double> nees(points.size(), 0.0);
  for (size_t k = 0; k < points.size(); ++k) {
    mo.volume = WorkingVolume{points[k], points[k]};
    const UncertaintyMapPoint pred = uncertainty_map(stated, mo).points[0];
    const Mat3 C_inv = (pred.cov_centroid + pred.cov_calibration).inverse();
    const std::vector<SlotPixel> slots = visible_pixels(sampled, points[k]);
    for (int i = 0; i < n; ++i) {
      Eigen::VectorXd z(F.cols());
      for (Eigen::Index j = 0; j < z.size(); ++j)
        z(j) = normal(rng);
      const camera::RigCalibration truth = test::perturbed_rig(sampled, F * z);
      std::vector<triangulate::Observation> obs;
      for (const SlotPixel& s : slots) {
        const auto& ct = truth.cameras[static_cast<size_t>(s.slot)];
        triangulate::Observation o;
        o.model = &sampled.cameras[static_cast<size_t>(s.slot)].model;
        o.T_c_w = sampled.cameras[static_cast<size_t>(s.slot)].T_c_w;
        o.pixel_px = *ct.model.project_world(ct.T_c_w, points[k]) +
                     Vec2(normal(rng), normal(rng)) * sigma_px;
        o.sigma_px = sigma_px;
        obs.push_back(o);
      }
      triangulate::Result r;
      EXPECT_TRUE(triangulate::triangulate(obs, triangulate::Options{}, r));
      const Vec3 e = r.p_w - points[k];
      nees[k] += e.dot(C_inv * e);
    }
  }
  return nees;
}

std::vector<Vec3> map_points_by_camera_count(const camera::RigCalibration& rig) {
  UncertaintyMapOptions mo;
  mo.volume_points = {7, 7, 7};
  const UncertaintyMap map = uncertainty_map(rig, mo);
  std::vector<Vec3> points;
  for (int k = 2; k <= 4; ++k)
    for (const auto& p : map.points)
      if (p.valid && p.cameras == k) {
        points.push_back(p.p_w);
        break;
      }
  return points;
}

TEST(UncertaintyMap, EqualsMonteCarloOfTriangulations) {
  // n draws per point (calibration from the rig's joint covariance, cross-camera terms
  // included, + centroid noise 0.2 px), 3 points (2, 3, 4 cameras): each NEES sum in the
  // two-sided 99.9 % interval of chi-square(3n).
  const int n = draws(400);
  const camera::RigCalibration rig =
      with_cross_covariance(sim::Simulator(scenario(), 1).calibrated_rig());
  const std::vector<Vec3> points = map_points_by_camera_count(rig);
  ASSERT_EQ(points.size(), 3u);
  const std::vector<double> nees = monte_carlo_nees(rig, rig, points, 0.2, n);
  const auto [lo, hi] = chi2_interval(3 * n);
  for (size_t k = 0; k < points.size(); ++k) {
    std::cout << "point " << k << " (" << k + 2 << " cameras): mean NEES " << nees[k] / n
              << " (3), interval " << lo / n << ".." << hi / n << "\n";
    EXPECT_GT(nees[k], lo);
    EXPECT_LT(nees[k], hi);
  }
  // The same draws scored against the per-camera blocks only (cross terms dropped) must fail
  // at the points seen by 3 and 4 cameras: the map uses the joint covariance.
  camera::RigCalibration blocks_only = rig;
  blocks_only.joint_covariance.resize(0, 0);
  const std::vector<double> wrong = monte_carlo_nees(rig, blocks_only, points, 0.2, n);
  for (size_t k = 1; k < points.size(); ++k) {
    std::cout << "per-camera blocks only, point " << k << ": mean NEES " << wrong[k] / n << "\n";
    EXPECT_GT(wrong[k], hi) << "point " << k;
  }
}

TEST(UncertaintyMap, MarksPointsSeenByFewerThanTwoCameras) {
  const camera::RigCalibration rig = sim::Simulator(scenario(), 1).calibrated_rig();
  UncertaintyMapOptions mo;
  mo.volume_points = {7, 7, 7};
  const UncertaintyMap map = uncertainty_map(rig, mo);
  int unseen = 0;
  for (const auto& p : map.points) {
    EXPECT_EQ(p.valid, p.cameras >= 2);
    EXPECT_EQ(p.cameras, static_cast<int>(visible_pixels(rig, p.p_w).size()));
    unseen += p.valid ? 0 : 1;
  }
  EXPECT_GT(unseen, 0);
  EXPECT_LT(unseen, static_cast<int>(map.points.size()));
}

TEST(CompareCalibrations, ScaleBarsGiveTheScaleErrorInClosedForm) {
  // a = truth; b = the rig scaled by 1.01 about the world origin (every camera centre moved
  // outwards): the same pixels triangulate 1.01 times further apart, so b's length error is
  // exactly 1 % of the bar, a's zero (noise-free pixels).
  const camera::RigCalibration truth = sim::Simulator(scenario(), 1).true_rig();
  camera::RigCalibration b = truth;
  for (auto& c : b.cameras)
    c.T_c_w.translation() *= 1.01;
  const Vec3 centre = map_points_by_camera_count(truth).back();  // seen by all 4 cameras
  survey::ScaleBarSet bars;
  std::vector<BarSighting> sightings;
  const std::vector<std::pair<Vec3, Vec3>> ends = {
      {centre + Vec3(-0.15, 0, 0), centre + Vec3(0.15, 0, 0)},
      {centre + Vec3(0, -0.1, -0.1), centre + Vec3(0, 0.1, 0.1)}};
  for (size_t j = 0; j < ends.size(); ++j) {
    const int ma = 300 + 2 * static_cast<int>(j), mb = ma + 1;
    bars.bars.push_back(
        {"bar" + std::to_string(j), ma, mb, (ends[j].second - ends[j].first).norm(), 5e-6});
    for (const auto& [mark, p] : {std::pair{ma, ends[j].first}, std::pair{mb, ends[j].second}})
      for (const SlotPixel& s : visible_pixels(truth, p))
        sightings.push_back(
            {truth.cameras[static_cast<size_t>(s.slot)].camera_id, mark, s.pixel_px});
  }
  CompareOptions o = small_options();
  const ComparisonResult r = compare_calibrations(truth, b, o, &bars, sightings);
  ASSERT_EQ(r.bars.size(), 2u);
  for (const auto& bar : r.bars) {
    ASSERT_TRUE(bar.valid) << bar.reason;
    EXPECT_NEAR(bar.error_a_m, 0.0, 1e-9);
    EXPECT_NEAR(bar.error_b_m, 0.01 * bar.length_m, 1e-9);
    EXPECT_GT(bar.u_a_m, 0.0);
  }
  EXPECT_NE(r.verdict.find("fail the length test"), std::string::npos) << r.verdict;
  EXPECT_NE(r.verdict.find("do not fly with that set"), std::string::npos) << r.verdict;
}

TEST(CompareCalibrations, VerdictNamesTheSetWithTheSmallerUncertainty) {
  // Seed 002's case: two consistent sets whose predicted uncertainties differ 2x. b states
  // twice a's standard uncertainties (covariance x 4) with the same parameters: consistent,
  // and a is better.
  const camera::RigCalibration a = sim::Simulator(scenario(), 1).calibrated_rig();
  camera::RigCalibration b = a;
  camera::set_joint_covariance(b, 4.0 * a.full_joint_covariance());
  const ComparisonResult r = compare_calibrations(a, b, small_options());
  EXPECT_TRUE(r.consistent);
  EXPECT_NEAR(r.u_b_m.rms / r.u_a_m.rms, 2.0, 1e-9);
  EXPECT_EQ(r.better, 'a') << r.verdict;
  const ComparisonResult swapped = compare_calibrations(b, a, small_options());
  EXPECT_EQ(swapped.better, 'b') << swapped.verdict;
}

std::string temp_dir() {
  const auto dir =
      std::filesystem::temp_directory_path() / ("storetrack_compare_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  return dir.string();
}

TEST(CompareCommand, DifferentRigsAreRefusedNamingFileAndField) {
  const std::string dir = temp_dir();
  const camera::RigCalibration a = sim::Simulator(scenario(), 1).calibrated_rig();
  camera::write_rig_calibration(a, dir + "/a.json");
  camera::RigCalibration fewer = a;
  fewer.cameras.pop_back();
  camera::write_rig_calibration(fewer, dir + "/fewer.json");
  camera::RigCalibration wider = a;
  camera::Intrinsics in = wider.cameras[1].model.intrinsics();
  in.width = 1280;
  wider.cameras[1].model = camera::CameraModel(in);
  camera::write_rig_calibration(wider, dir + "/wider.json");
  for (const auto& [file, expected] :
       {std::pair<std::string, std::string>{"fewer.json", "fewer.json: /cameras: 3 cameras, "},
        {"wider.json", "wider.json: /cameras/1/image_size: 1280x1024, "}}) {
    calibapp::CompareArgs args;
    args.a = dir + "/a.json";
    args.b = dir + "/" + file;
    args.output = dir + "/out.json";
    std::ostringstream out, err;
    EXPECT_EQ(calibapp::run_compare(args, out, err), 2);
    EXPECT_NE(err.str().find(expected), std::string::npos) << err.str();
  }
}

TEST(CompareCommand, WritesResultsEndToEnd) {
  const std::string dir = std::getenv("STORETRACK_COMPARE_WRITE_DIR")
                              ? std::getenv("STORETRACK_COMPARE_WRITE_DIR")
                              : temp_dir();
  std::filesystem::create_directories(dir);
  camera::write_rig_calibration(sim::Simulator(scenario(), 1).calibrated_rig(), dir + "/a.json");
  camera::write_rig_calibration(sim::Simulator(scenario(), 2).calibrated_rig(), dir + "/b.json");
  calibapp::CompareArgs args;
  args.a = dir + "/a.json";
  args.b = dir + "/b.json";
  args.volume.points_per_axis = 7;
  args.output = dir + "/compare.json";
  std::ostringstream out, err;
  ASSERT_EQ(calibapp::run_compare(args, out, err), 0) << err.str();
  EXPECT_NE(out.str().find("verdict: "), std::string::npos);
  std::ifstream f(args.output);
  const auto doc = nlohmann::json::parse(f);
  EXPECT_EQ(doc["kind"], "storetrack-calib-compare");
  EXPECT_EQ(doc["cameras"].size(), 4u);
  EXPECT_EQ(doc["volume_points"].size(), 343u);
  calibapp::UncertaintyMapArgs map_args;
  map_args.rig = args.a;
  map_args.volume.points_per_axis = 9;
  map_args.output = dir + "/map.json";
  ASSERT_EQ(calibapp::run_uncertainty_map(map_args, out, err), 0) << err.str();
  std::ifstream g(map_args.output);
  const auto map = nlohmann::json::parse(g);
  EXPECT_EQ(map["points"].size(), 729u);
}

}  // namespace
}  // namespace storetrack::calib
