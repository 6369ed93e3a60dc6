// storetrack-eval lme: the length error and its u against closed forms, the MPE verdict, and
// bad input naming the file and field (issue 10): missing columns, a bar whose mark is missing,
// a scale bar seen by one camera (through the host: its mark has no triangulation), too few
// repetitions, a malformed bar file, MPE options.
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>

#include "lme_command.hpp"
#include "lme_recordings.hpp"
#include "storetrack/eval/length_measuring_error.hpp"

namespace storetrack {
namespace {

namespace fs = std::filesystem;

const char* const kHeader =
    "trigger_seq [1],mark_id [1],body [p|s|?],excluded [0|1],x_w [m],y_w [m],z_w [m],"
    "u_x_w [m],u_y_w [m],u_z_w [m],camera_id [1],cov_xy_w [m^2],cov_xz_w [m^2],cov_yz_w [m^2]";

/// Two camera rows of one triangulated mark (the host writes one per camera).
std::string mark_rows(int seq, int id, double x, double y, double z, double cov_xy = 0,
                      int cameras = 2) {
  std::ostringstream o;
  o.precision(17);
  for (int c = 0; c < cameras; ++c)
    o << seq << "," << id << ",?,0," << x << "," << y << "," << z << ",0.0001,0.0002,0.0003," << c
      << "," << cov_xy << ",0,0\n";
  return o.str();
}

survey::ScaleBarSet one_bar(double length_m = 1.0, double u_m = 3e-6) {
  survey::ScaleBarSet s;
  s.name = "test";
  s.bars = {{"diagonal_1", 300, 301, length_m, u_m}};
  return s;
}

template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const eval::EvalInputError& e) {
    return e.what();
  } catch (const survey::SurveyFileError& e) {
    return e.what();
  }
  return {};
}

eval::LmeOptions options(int min_repetitions = 1) {
  eval::LmeOptions o;
  o.min_repetitions = min_repetitions;
  return o;
}

TEST(LmeInput, LengthErrorAndUncertaintyMatchClosedForm) {
  // Bar along (1, 1, 0)/sqrt(2), measured 0.3 mm long: u^2 = sum over both marks of
  // (Sxx + Syy + 2 Sxy) / 2 + u_bar^2.
  const double h = (1.0 + 3e-4) / std::sqrt(2.0), cov_xy = 1.5e-8;
  const std::string csv = std::string(kHeader) + "\n" + mark_rows(7, 300, 1, 2, 3, cov_xy) +
                          mark_rows(7, 301, 1 + h, 2 + h, 3, cov_xy);
  const eval::LmeResult r =
      eval::evaluate_lme({eval::parse_marks_csv(csv, "a.csv")}, one_bar(), "bars.json", options());
  ASSERT_EQ(r.bars.size(), 1u);
  ASSERT_EQ(r.bars[0].measurements.size(), 1u);
  const eval::LengthMeasurement& m = r.bars[0].measurements[0];
  EXPECT_NEAR(m.error_m, 3e-4, 1e-12);
  const double mark_var = (1e-8 + 4e-8 + 2 * cov_xy) / 2;
  EXPECT_NEAR(m.u_m, std::sqrt(2 * mark_var + 9e-12), 1e-12);
  EXPECT_TRUE(r.full_covariance);
  EXPECT_EQ(r.bars[0].stats.n, 1);
  EXPECT_NEAR(r.bars[0].stats.max_abs_m, 3e-4, 1e-12);
}

TEST(LmeInput, FileWithoutCovarianceColumnsIsFlaggedPerAxis) {
  // An older marks CSV (no cov_*_w): S diagonal, u^2 = sum over both marks of (Sxx + Syy) / 2,
  // and the result says so.
  std::string header = kHeader;
  header.resize(header.find(",cov_xy_w"));
  std::string rows = mark_rows(7, 300, 1, 2, 3) +
                     mark_rows(7, 301, 1 + 1 / std::sqrt(2.0), 2 + 1 / std::sqrt(2.0), 3);
  for (size_t at = rows.find(",0,0,0\n"); at != std::string::npos; at = rows.find(",0,0,0\n", at))
    rows.erase(at, 6);
  const eval::LmeResult r =
      eval::evaluate_lme({eval::parse_marks_csv(header + "\n" + rows, "old.csv")}, one_bar(1.0, 0),
                         "bars.json", options());
  EXPECT_FALSE(r.full_covariance);
  EXPECT_NEAR(r.bars.at(0).measurements.at(0).u_m, std::sqrt(1e-8 + 4e-8), 1e-12);
}

TEST(LmeInput, StatisticsAndMpeVerdict) {
  // Three exposures with LME +0.1, -0.2, +0.4 mm: max 0.4, mean 0.1, sigma sqrt(0.09) = 0.3 mm.
  std::string csv = std::string(kHeader) + "\n";
  const double errors[] = {1e-4, -2e-4, 4e-4};
  for (int k = 0; k < 3; ++k)
    csv += mark_rows(k, 300, 0, 0, 0) + mark_rows(k, 301, 1 + errors[k], 0, 0);
  const eval::MarksRecording rec = eval::parse_marks_csv(csv, "a.csv");
  eval::LmeOptions o = options();
  o.mpe = {true, 0.21e-3, 5000};  // MPE(1 m) = 0.21 + 0.2 = 0.41 mm: every |LME| within
  eval::LmeResult r = eval::evaluate_lme({rec}, one_bar(1.0, 0), "bars.json", o);
  const eval::LmeStatistics& s = r.bars[0].stats;
  EXPECT_NEAR(s.max_abs_m, 4e-4, 1e-12);
  EXPECT_NEAR(s.mean_m, 1e-4, 1e-12);
  EXPECT_NEAR(s.sd_m, 3e-4, 1e-12);
  EXPECT_NEAR(r.bars[0].mpe_m, 4.1e-4, 1e-15);
  EXPECT_TRUE(r.pass);
  o.mpe = {true, 0.35e-3, 0};  // constant 0.35 mm: the 0.4 mm error exceeds it
  r = eval::evaluate_lme({rec}, one_bar(1.0, 0), "bars.json", o);
  EXPECT_FALSE(r.pass);
  EXPECT_EQ(r.overall.exceeding_mpe, 1);
  EXPECT_EQ(r.repetitions.at(0).stats.n, 3);
}

TEST(LmeInput, MissingColumnNamesFileAndField) {
  std::string header = kHeader;
  header.replace(header.find("cov_yz_w [m^2]"), 14, "other");
  const std::string e = error_of(
      [&] { eval::parse_marks_csv(header + "\n" + mark_rows(1, 300, 0, 0, 0), "rep1.csv"); });
  EXPECT_NE(e.find("rep1.csv:1: cov_yz_w: missing column"), std::string::npos) << e;
  header = kHeader;
  header.replace(header.find("z_w [m]"), 7, "zz");
  const std::string e2 = error_of([&] { eval::parse_marks_csv(header + "\n", "rep2.csv"); });
  EXPECT_NE(e2.find("rep2.csv:1: z_w: missing column"), std::string::npos) << e2;
}

TEST(LmeInput, BarWhoseMarkIsMissingNamesFileAndMark) {
  const std::string csv = std::string(kHeader) + "\n" + mark_rows(1, 300, 0, 0, 0);
  const std::string e = error_of([&] {
    eval::evaluate_lme({eval::parse_marks_csv(csv, "rep3.csv")}, one_bar(), "bars.json", options());
  });
  EXPECT_NE(e.find("rep3.csv: mark_id: mark 301 (bar 'diagonal_1' mark_b of bars.json) has no "
                   "triangulated position"),
            std::string::npos)
      << e;
}

TEST(LmeInput, MarkWithOneCameraRowNamesLineAndField) {
  const std::string csv =
      std::string(kHeader) + "\n" + mark_rows(1, 300, 0, 0, 0) + mark_rows(1, 301, 1, 0, 0, 0, 1);
  const std::string e = error_of([&] {
    eval::evaluate_lme({eval::parse_marks_csv(csv, "rep4.csv")}, one_bar(), "bars.json", options());
  });
  EXPECT_NE(e.find("rep4.csv:4: camera_id: mark 301"), std::string::npos) << e;
  EXPECT_NE(e.find("one camera row"), std::string::npos) << e;
}

TEST(LmeInput, ScaleBarSeenByOneCameraThroughTheHost) {
  // The simulator's bar 2 (marks 304, 305): every camera but camera 0 loses mark 305, so the
  // host cannot triangulate it and writes no row for it.
  const sim::Scenario scenario = sim::load_scenario(test::scenario_path("scale_bars"));
  const sim::Simulator sim(scenario, 3);
  const std::string csv =
      test::scale_bar_marks_csv(sim, sim.calibrated_rig(), 2, nullptr,
                                [](int camera, int id) { return id == 305 && camera != 0; });
  const std::string e = error_of([&] {
    eval::evaluate_lme({eval::parse_marks_csv(csv, "rep5.csv")}, sim.scale_bar_set(false),
                       "bars.json", options());
  });
  EXPECT_NE(e.find("rep5.csv: mark_id: mark 305 (bar 'scale_bar_2' mark_b of bars.json)"),
            std::string::npos)
      << e;
  // Without the fault every bar is measured in both exposures.
  const eval::LmeResult ok = eval::evaluate_lme(
      {eval::parse_marks_csv(test::scale_bar_marks_csv(sim, sim.calibrated_rig(), 2), "ok.csv")},
      sim.scale_bar_set(false), "bars.json", options());
  for (const eval::BarLme& b : ok.bars)
    EXPECT_EQ(b.stats.n, 2) << b.bar.id;
}

TEST(LmeInput, RigWithoutObservationColumnsNamesFileAndColumn) {
  // --rig re-triangulates each end from its observations: a CSV without them is refused, the
  // first missing column named; a camera the rig lacks is named with its line.
  const sim::Simulator sim(sim::load_scenario(test::scenario_path("scale_bars")), 3);
  std::istringstream full(test::scale_bar_marks_csv(sim, sim.calibrated_rig(), 1));
  std::string csv, line;
  while (std::getline(full, line)) {  // the first 11 columns: up to u_z_w
    size_t at = 0;
    for (int comma = 0; comma < 11 && at != std::string::npos; ++comma)
      at = line.find(',', at + 1);
    csv += line.substr(0, at) + "\n";
  }
  eval::LmeOptions with_rig = options();
  with_rig.rig = sim.calibrated_rig();
  const std::string e = error_of([&] {
    eval::evaluate_lme({eval::parse_marks_csv(csv, "noobs.csv")}, sim.scale_bar_set(false),
                       "bars.json", with_rig);
  });
  EXPECT_NE(e.find("noobs.csv:1: camera_id: missing column in the header"), std::string::npos) << e;
  EXPECT_NE(e.find(": camera_id: missing column in the header"), std::string::npos) << e;
  camera::RigCalibration other = sim.calibrated_rig();
  other.cameras.erase(other.cameras.begin());
  with_rig.rig = other;
  const std::string e2 = error_of([&] {
    eval::evaluate_lme({eval::parse_marks_csv(
                           test::scale_bar_marks_csv(sim, sim.calibrated_rig(), 1), "rep7.csv")},
                       sim.scale_bar_set(false), "bars.json", with_rig);
  });
  EXPECT_NE(e2.find("rep7.csv:"), std::string::npos) << e2;
  EXPECT_NE(e2.find(": camera_id: camera 0 is not in the rig calibration"), std::string::npos)
      << e2;
}

TEST(LmeInput, TooFewRepetitionsNamesBarAndCount) {
  const std::string csv =
      std::string(kHeader) + "\n" + mark_rows(1, 300, 0, 0, 0) + mark_rows(1, 301, 1, 0, 0);
  const eval::MarksRecording rec = eval::parse_marks_csv(csv, "rep6.csv");
  const std::string e = error_of([&] {
    eval::evaluate_lme({rec, rec}, one_bar(), "bars.json", options(3));
  });
  EXPECT_NE(e.find("bars.json: bars: bar 'diagonal_1' measured in 2 of the 2 marks CSV"),
            std::string::npos)
      << e;
  EXPECT_NE(e.find("at least 3 repetitions"), std::string::npos) << e;
}

TEST(LmeInput, MalformedBarFileNamesField) {
  const std::string missing = error_of([] {
    survey::parse_scale_bars(
        R"({"format": "storetrack-scale-bars", "version": 1, "bars": [
            {"id": "a", "mark_a": 1, "mark_b": 2, "length_m": 1, "u_length_m": 0},
            {"id": "b", "mark_a": 3, "mark_b": 4, "u_length_m": 0}]})",
        "bars.json");
  });
  EXPECT_NE(missing.find("bars.json: bars[1].length_m: missing"), std::string::npos) << missing;
  const std::string shared = error_of([] {
    survey::parse_scale_bars(
        R"({"format": "storetrack-scale-bars", "version": 1, "bars": [
            {"id": "a", "mark_a": 1, "mark_b": 2, "length_m": 1, "u_length_m": 0},
            {"id": "b", "mark_a": 2, "mark_b": 4, "length_m": 1, "u_length_m": 0}]})",
        "bars.json");
  });
  EXPECT_NE(shared.find("bars.json: bars[1].mark_a: mark used by two bars"), std::string::npos)
      << shared;
  const std::string negative = error_of([] {
    survey::parse_scale_bars(
        R"({"format": "storetrack-scale-bars", "version": 1, "bars": [
            {"id": "a", "mark_a": 1, "mark_b": 2, "length_m": -1, "u_length_m": 0}]})",
        "bars.json");
  });
  EXPECT_NE(negative.find("bars.json: bars[0].length_m: expected a number in > 0, got -1"),
            std::string::npos)
      << negative;
}

TEST(LmeInput, SimulatorBarFileRoundTrips) {
  const sim::Simulator sim(sim::load_scenario(test::scenario_path("scale_bars")), 1);
  const survey::ScaleBarSet truth = sim.scale_bar_set(true);
  const survey::ScaleBarSet read =
      survey::parse_scale_bars(survey::format_scale_bars(truth), "sim");
  ASSERT_EQ(read.bars.size(), 7u);
  for (size_t j = 0; j < read.bars.size(); ++j) {
    const survey::ScaleBar& b = read.bars[j];
    // The truth: the distance of the two marks' true positions in the world.
    const double length = (sim.mark_position_w(b.mark_b, sim.trigger_tai_ns(0)) -
                           sim.mark_position_w(b.mark_a, sim.trigger_tai_ns(0)))
                              .norm();
    EXPECT_NEAR(b.length_m, length, 1e-12) << b.id;
    EXPECT_EQ(b.mark_a, 300 + 2 * static_cast<int>(j));
    EXPECT_NEAR(b.u_length_m, std::sqrt(2.0) * 3.5e-6, 1e-15);
  }
}

TEST(LmeInput, MpeOptionsAreAPairOrAConstant) {
  const fs::path dir = fs::temp_directory_path() / ("lme_cli_" + std::to_string(getpid()));
  fs::create_directories(dir);
  std::ofstream(dir / "a.csv") << kHeader << "\n"
                               << mark_rows(1, 300, 0, 0, 0) << mark_rows(1, 301, 1, 0, 0);
  survey::write_scale_bars(one_bar(), (dir / "bars.json").string());
  const auto run = [&](std::vector<std::string> extra, std::string& out, std::string& err) {
    std::vector<std::string> args = {"storetrack-eval",
                                     "lme",
                                     (dir / "a.csv").string(),
                                     "--bars",
                                     (dir / "bars.json").string(),
                                     "-o",
                                     (dir / "r.json").string(),
                                     "--min-repetitions",
                                     "1"};
    args.insert(args.end(), extra.begin(), extra.end());
    std::vector<char*> argv;
    for (std::string& a : args)
      argv.push_back(a.data());
    evalapp::LmeArgs la;
    cli::Command app{"test"};
    evalapp::add_lme_command(app, la);
    std::ostringstream o, e;
    int rc = app.parse(static_cast<int>(argv.size()), argv.data());
    if (rc < 0) rc = evalapp::finish_lme_args(la, e);
    if (rc < 0) rc = evalapp::run_lme(la, o, e);
    out = o.str();
    err = e.str();
    return rc;
  };
  std::string out, err;
  EXPECT_EQ(run({"--mpe-a", "1e-4"}, out, err), 2);
  EXPECT_NE(err.find("--mpe-a with --mpe-k"), std::string::npos) << err;
  EXPECT_EQ(run({"--mpe", "1e-4", "--mpe-k", "1000"}, out, err), 2);
  EXPECT_EQ(run({"--mpe-a", "1e-4", "--mpe-k", "10000"}, out, err), 0) << err;
  EXPECT_NE(out.find("MPE = 0.100 mm + L / 10000"), std::string::npos) << out;
  EXPECT_NE(out.find("verdict: PASS"), std::string::npos) << out;
  fs::remove_all(dir);
}

}  // namespace
}  // namespace storetrack
