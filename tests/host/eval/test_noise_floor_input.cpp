// storetrack-eval noise-floor: closed forms on hand-made records, the rig axes and stereo angles
// against the scenario's geometry, bad input naming the file and field (issue 10), and the
// program end to end on a record written by the host's own writer.
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>

#include "noise_floor_command.hpp"
#include "noise_floor_recordings.hpp"
#include "storetrack/eval/noise_floor.hpp"

namespace storetrack {
namespace {

// A literal (GCC 12 -O3 warns falsely on test::scenario_path's concatenation here).
constexpr const char* kStaticScenario = STORETRACK_SCENARIO_DIR "/static.json";

namespace fs = std::filesystem;
using geometry::Vec3;

const char* const kShortHeader =
    "trigger_seq [1],reference_mid_tai_ns [ns],mark_id [1],body [p|s|?],excluded [0|1],x_w [m],"
    "y_w [m],z_w [m],u_x_w [m],u_y_w [m],u_z_w [m]";

survey::RigidBodySurvey world_survey() {
  survey::RigidBodySurvey s;
  s.name = "reference";
  s.frame = 'w';
  s.marks = {{1, {1.0, 2.0, 3.0}, 1e-4}, {2, {1.1, 2.0, 3.0}, 1e-4}};
  return s;
}

/// Mark 1 at x = 1.000 + dx1, mark 2 at x = 1.100 + dx2 (y, z exact), one exposure per line.
std::string record(const std::vector<std::pair<double, double>>& dx, int extra_mark = -1) {
  std::ostringstream o;
  o << kShortHeader << "\n";
  int seq = 0;
  for (const auto& [a, b] : dx) {
    o << seq << "," << seq * 2500000 << ",1,p,0," << 1.0 + a << ",2,3,0.001,0.001,0.001\n";
    o << seq << "," << seq * 2500000 << ",2,p,0," << 1.1 + b << ",2,3,0.001,0.001,0.001\n";
    ++seq;
  }
  if (extra_mark >= 0) o << 0 << ",0," << extra_mark << ",p,0,1,2,3,0.001,0.001,0.001\n";
  return o.str();
}

std::vector<std::pair<double, double>> ten_exposures() {
  std::vector<std::pair<double, double>> dx;
  for (int i = 0; i < 10; ++i)  // mark 1: +-1 mm alternating, mark 2: 0.5 mm constant
    dx.push_back({i % 2 ? 0.001 : -0.001, 0.0005});
  return dx;
}

template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const eval::EvalInputError& e) {
    return e.what();
  }
  return {};
}

// Closed forms: mark 1 alternates -1, +1 mm (mean 0, s = sqrt(10/9) mm), mark 2 sits 0.5 mm off.
TEST(NoiseFloorInput, ClosedFormOfAHandMadeRecord) {
  const eval::MarksRecording rec = eval::parse_marks_csv(record(ten_exposures()), "r.csv");
  const eval::NoiseFloorResult r =
      eval::evaluate_noise_floor(rec, world_survey(), "s.json", nullptr, "");
  ASSERT_EQ(r.marks.size(), 2u);
  EXPECT_EQ(r.exposures, 10);
  EXPECT_NEAR(r.duration_s, 9 * 2.5e-3, 1e-12);
  const eval::AxisNoise& x1 = r.marks[0].world[0];
  const eval::AxisNoise& x2 = r.marks[1].world[0];
  EXPECT_NEAR(x1.temporal_sd_m, 0.001 * std::sqrt(10.0 / 9.0), 1e-12);
  EXPECT_NEAR(x1.bias_m, 0, 1e-12);
  EXPECT_NEAR(x2.temporal_sd_m, 0, 1e-12);
  EXPECT_NEAR(x2.bias_m, 0.0005, 1e-12);
  EXPECT_NEAR(x2.u_bias_m, 1e-4, 1e-12);  // the survey's sigma alone
  EXPECT_FALSE(x2.bias_within_k_u);       // 0.5 mm > 2 x 0.1 mm
  EXPECT_NEAR(x1.u_stated_m, 0.001, 1e-12);
  EXPECT_EQ(x1.u_centroid_m, 0);  // no rig: unknown, no ratio
  const eval::AxisNoiseSummary& s = r.world_summary[0];
  EXPECT_NEAR(s.temporal_sd_mean_m, 0.001 * std::sqrt(10.0 / 9.0) / 2, 1e-12);
  EXPECT_NEAR(s.bias_mean_m, 0.00025, 1e-12);
  // Spatial: displacements {-1, 0.5} or {+1, 0.5} mm: sd over 2 marks = |d1 - d2| / sqrt(2).
  EXPECT_NEAR(s.spatial_sd_mean_m, (0.0015 + 0.0005) / 2 / std::sqrt(2.0), 1e-12);
  ASSERT_EQ(r.distances.size(), 1u);
  const eval::DistanceError& d = r.distances[0];
  EXPECT_NEAR(d.reference_m, 0.1, 1e-12);
  EXPECT_NEAR(d.measured_m, 0.1005, 1e-12);
  EXPECT_NEAR(d.error_percent, 0.5, 1e-9);
  // Without observation columns the image-coordinate part is left out, by name.
  EXPECT_FALSE(r.has_observations);
  EXPECT_NE(r.image_coordinates_note.find("u_obs"), std::string::npos) << r.image_coordinates_note;
  EXPECT_TRUE(r.cameras.empty());
}

TEST(NoiseFloorInput, MissingColumnNamesFileAndField) {
  std::string text = record(ten_exposures());
  text.replace(text.find("y_w [m],"), 8, "");
  const std::string e = error_of([&] { eval::parse_marks_csv(text, "rec.csv"); });
  EXPECT_NE(e.find("rec.csv:1: y_w: missing column"), std::string::npos) << e;
}

TEST(NoiseFloorInput, TooFewExposures) {
  const eval::MarksRecording rec =
      eval::parse_marks_csv(record({{0, 0}, {0.001, 0}, {0, 0}, {0, 0.001}, {0, 0}}), "short.csv");
  const std::string e =
      error_of([&] { eval::evaluate_noise_floor(rec, world_survey(), "s.json", nullptr, ""); });
  EXPECT_NE(e.find("short.csv: trigger_seq: 5 exposures; the noise floor needs at least 10"),
            std::string::npos)
      << e;
}

TEST(NoiseFloorInput, MarkNotInTheSurveyNamesFileLineAndSurvey) {
  const eval::MarksRecording rec = eval::parse_marks_csv(record(ten_exposures(), 7), "rec.csv");
  const std::string e =
      error_of([&] { eval::evaluate_noise_floor(rec, world_survey(), "s.json", nullptr, ""); });
  EXPECT_NE(e.find("rec.csv:22: mark_id: mark 7 is not in the survey s.json"), std::string::npos)
      << e;
}

TEST(NoiseFloorInput, SurveyMustBeInTheWorldFrame) {
  const eval::MarksRecording rec = eval::parse_marks_csv(record(ten_exposures()), "rec.csv");
  survey::RigidBodySurvey pylon = world_survey();
  pylon.frame = 'p';
  const std::string e =
      error_of([&] { eval::evaluate_noise_floor(rec, pylon, "pylon.json", nullptr, ""); });
  EXPECT_NE(e.find("pylon.json: frame"), std::string::npos) << e;
}

TEST(NoiseFloorInput, OneMarkIsNotEnough) {
  survey::RigidBodySurvey s = world_survey();
  const eval::MarksRecording rec = eval::parse_marks_csv(record(ten_exposures()), "rec.csv");
  eval::NoiseFloorOptions options;
  options.min_samples = 10;
  // Mark 2 flagged as the store: body p leaves one mark.
  std::string text = record(ten_exposures());
  for (size_t at = text.find(",2,p,"); at != std::string::npos; at = text.find(",2,p,", at))
    text.replace(at, 5, ",2,s,");
  const eval::MarksRecording one = eval::parse_marks_csv(text, "one.csv");
  const std::string e =
      error_of([&] { eval::evaluate_noise_floor(one, s, "s.json", nullptr, "", options); });
  EXPECT_NE(e.find("one.csv: mark_id: 1 mark(s)"), std::string::npos) << e;
}

// The rig axes and stereo angles of the static scene against its geometry (scenario file): the
// pylon frame is the world frame rotated by identity, so the cameras' viewing directions are
// look_at - position; the rig is mirror-symmetric in y, so in-plane 1 (the baseline) is +-y.
TEST(NoiseFloorInput, RigAxesAndStereoAnglesOfTheStaticScene) {
  const sim::Scenario scenario = sim::load_scenario(kStaticScenario);
  const sim::Simulator sim(scenario, 4242);
  const camera::RigCalibration rig = sim.calibrated_rig();
  Vec3 view = Vec3::Zero();
  for (const auto& c : scenario.cameras)
    view += (c.look_at_p_m - c.position_p_m).normalized();
  const eval::RigAxes axes = eval::rig_axes(rig);
  // Calibration error 5e-5 rad per camera: the mean direction within 1e-3 rad.
  EXPECT_LT(std::acos(std::min(1.0, axes.axis[2].dot(view.normalized()))), 1e-3);
  EXPECT_GT(std::abs(axes.axis[0].y()), 0.999);
  EXPECT_NEAR(axes.axis[2].dot(axes.axis[0]), 0, 1e-12);

  const std::string csv = test::simulated_static_record(sim, rig);
  const eval::MarksRecording rec = eval::parse_marks_csv(csv, "record");
  eval::NoiseFloorOptions options;
  options.store = true;
  const eval::NoiseFloorResult r =
      eval::evaluate_noise_floor(rec, test::true_static_survey(sim), "truth", &rig, "rig", options);
  ASSERT_FALSE(r.stereo_angles.empty());
  // Truth: the scenario's camera positions (pylon = world axes, T_w_p translation added) and
  // the marks' true positions; the measured means and calibrated centres differ by < 1 mm at
  // >= 1 m, i.e. < 1e-3 rad.
  const Vec3 t_w_p(1.5, 3.2, 0.6);
  double worst = 0;
  for (const eval::StereoAngle& a : r.stereo_angles) {
    const Vec3 p = test::true_static_survey(sim).find(a.mark_id)->p_body;
    const Vec3 ca = scenario.cameras[static_cast<size_t>(a.camera_a)].position_p_m + t_w_p;
    const Vec3 cb = scenario.cameras[static_cast<size_t>(a.camera_b)].position_p_m + t_w_p;
    const double truth = std::acos((ca - p).normalized().dot((cb - p).normalized()));
    worst = std::max(worst, std::abs(a.stereo_angle_rad - truth));
  }
  std::printf("%zu stereo angles, worst difference to the scenario's geometry %.2e rad\n",
              r.stereo_angles.size(), worst);
  EXPECT_LT(worst, 1e-3);
  EXPECT_LT(r.max_retriangulation_m, 1e-5);  // the offline triangulation is the host's
}

TEST(NoiseFloorInput, CameraNotInTheRig) {
  const sim::Scenario scenario = sim::load_scenario(kStaticScenario);
  const sim::Simulator sim(scenario, 4243);
  const std::string csv = test::simulated_static_record(sim, sim.calibrated_rig());
  camera::RigCalibration rig = sim.calibrated_rig();
  rig.cameras.pop_back();  // camera 3 missing
  const eval::MarksRecording rec = eval::parse_marks_csv(csv, "rec.csv");
  eval::NoiseFloorOptions options;
  options.store = true;
  const std::string e = error_of([&] {
    eval::evaluate_noise_floor(rec, test::true_static_survey(sim), "s.json", &rig, "rig.json",
                               options);
  });
  EXPECT_NE(e.find("camera_id: camera 3 is not in the rig rig.json"), std::string::npos) << e;
  EXPECT_EQ(e.find("rec.csv:"), 0u) << e;
}

// The host writes "nan" for a centroid it could not look up: kept in the record, counted per
// camera as without pixel, left out of the offline triangulation (the mark keeps >= 2 cameras).
TEST(NoiseFloorInput, ObservationWithoutPixelIsCounted) {
  const sim::Scenario scenario = sim::load_scenario(kStaticScenario);
  const sim::Simulator sim(scenario, 4245);
  std::string csv = test::simulated_static_record(sim, sim.calibrated_rig());
  // Row 2 (the first data row): its 13th cell, u_obs.
  const size_t row = csv.find('\n') + 1;
  size_t begin = row;
  for (int cell = 0; cell < 12; ++cell)
    begin = csv.find(',', begin) + 1;
  csv.replace(begin, csv.find(',', begin) - begin, "nan");
  const eval::MarksRecording rec = eval::parse_marks_csv(csv, "rec.csv");
  ASSERT_TRUE(rec.has_observations);
  EXPECT_TRUE(std::isnan(rec.samples[0].observations[0].pixel_px.x()));
  const camera::RigCalibration rig = sim.calibrated_rig();
  eval::NoiseFloorOptions options;
  options.store = true;
  const eval::NoiseFloorResult r =
      eval::evaluate_noise_floor(rec, test::true_static_survey(sim), "truth", &rig, "rig", options);
  std::int64_t without = 0;
  for (const eval::CameraImageNoise& c : r.cameras)
    without += c.without_pixel;
  EXPECT_EQ(without, 1);
  // A non-finite stated sigma is still refused (its cell found by the header's name).
  const std::string header = csv.substr(0, row);
  int sigma_cell = 0;
  for (size_t at = 0; header.compare(at, 6, "sigma ") != 0; at = header.find(',', at) + 1)
    ++sigma_cell;
  std::string bad = csv;
  size_t sigma_begin = row;
  for (int cell = 0; cell < sigma_cell; ++cell)
    sigma_begin = bad.find(',', sigma_begin) + 1;
  bad.replace(sigma_begin, bad.find_first_of(",\n", sigma_begin) - sigma_begin, "inf");
  const std::string e = error_of([&] { eval::parse_marks_csv(bad, "rec.csv"); });
  EXPECT_NE(e.find("rec.csv:2: sigma: not finite"), std::string::npos) << e;
}

TEST(NoiseFloorInput, ProgramEndToEndOnHostWrittenFiles) {
  const fs::path dir = fs::temp_directory_path() / ("st_noise_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const sim::Scenario scenario = sim::load_scenario(kStaticScenario);
  const sim::Simulator sim(scenario, 4244);
  evalapp::NoiseFloorArgs args;
  args.marks_csv = (dir / "record.csv").string();
  std::ofstream(args.marks_csv) << test::simulated_static_record(sim, sim.calibrated_rig());
  args.survey = (dir / "reference.json").string();
  survey::write_survey(test::true_static_survey(sim), args.survey);
  args.rig = (dir / "rig.json").string();
  camera::write_rig_calibration(sim.calibrated_rig(), args.rig);
  args.options.store = true;
  args.output = (dir / "result.json").string();
  std::ostringstream out, err;
  EXPECT_EQ(evalapp::run_noise_floor(args, out, err), 0) << err.str();
  EXPECT_NE(out.str().find("k = 2"), std::string::npos) << out.str();
  EXPECT_NE(out.str().find("out_of_plane"), std::string::npos) << out.str();
  std::ifstream result(args.output);
  const nlohmann::json doc = nlohmann::json::parse(result);
  EXPECT_EQ(doc["format"], "storetrack-eval-noise-floor");
  EXPECT_EQ(doc["exposures"], 100);
  EXPECT_TRUE(doc["has_image_coordinates"].get<bool>());
  EXPECT_EQ(doc["cameras"].size(), 4u);
  // A survey without a seen mark stops the program with the record's file, line and survey.
  const int seen = doc["marks"][0]["mark_id"];
  survey::RigidBodySurvey partial = test::true_static_survey(sim);
  partial.marks.erase(std::find_if(partial.marks.begin(), partial.marks.end(),
                                   [&](const survey::SurveyedMark& m) { return m.id == seen; }));
  survey::write_survey(partial, args.survey);
  std::ostringstream out2, err2;
  EXPECT_EQ(evalapp::run_noise_floor(args, out2, err2), 2);
  EXPECT_NE(err2.str().find(args.marks_csv + ":"), std::string::npos) << err2.str();
  EXPECT_NE(err2.str().find("mark_id: mark " + std::to_string(seen) + " is not in the survey " +
                            args.survey),
            std::string::npos)
      << err2.str();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace storetrack
