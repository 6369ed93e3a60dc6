// storetrack-eval type-a: bad input names the file and field (issue 10), and the program runs
// end to end on marks CSVs written by the host's own writer.
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>

#include "eval_commands.hpp"
#include "storetrack/eval/type_a.hpp"
#include "type_a_recordings.hpp"

namespace storetrack {
namespace {

namespace fs = std::filesystem;

const char* const kHeader =
    "trigger_seq [1],reference_mid_tai_ns [ns],mark_id [1],body [p|s|?],excluded [0|1],x_w [m],"
    "y_w [m],z_w [m],u_x_w [m],u_y_w [m],u_z_w [m],camera_id [1]";

survey::RigidBodySurvey world_survey() {
  survey::RigidBodySurvey s;
  s.name = "reference";
  s.frame = 'w';
  s.marks = {{1, {1.0, 2.0, 3.0}, 1e-4}, {2, {1.5, 2.0, 3.0}, 1e-4}};
  return s;
}

std::string row(int seq, int id, double x, const char* u_y = "0.001") {
  std::ostringstream o;
  o << seq << ",0," << id << ",p,0," << x << ",2,3,0.001," << u_y << ",0.001,0\n";
  return o.str();
}

/// The message of the EvalInputError `f` throws (empty when it throws none).
template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const eval::EvalInputError& e) {
    return e.what();
  }
  return {};
}

TEST(TypeAInput, TheHostsHeaderIsAccepted) {
  EXPECT_NO_THROW(
      eval::parse_marks_csv(std::string(hostapp::kMarksCsvHeader) + "\n" +
                                "5,0,1,p,0,1,2,3,0.001,0.001,0.001,0,1,2,0,0,0.1,0,0,0\n",
                            "host.csv"));
}

TEST(TypeAInput, MissingColumnNamesFileAndField) {
  std::string header = kHeader;
  header.replace(header.find("u_y_w [m],"), 10, "");
  const std::string e =
      error_of([&] { eval::parse_marks_csv(header + "\n1,0,1,p,0,1,2,3,1,1,0\n", "rep1.csv"); });
  EXPECT_NE(e.find("rep1.csv:1"), std::string::npos) << e;
  EXPECT_NE(e.find("u_y_w"), std::string::npos) << e;
  EXPECT_NE(e.find("missing column"), std::string::npos) << e;
}

TEST(TypeAInput, NonFiniteValueNamesFileLineAndField) {
  const std::string e = error_of([&] {
    eval::parse_marks_csv(std::string(kHeader) + "\n" + row(1, 1, 1.0) + row(2, 1, NAN),
                          "rep2.csv");
  });
  EXPECT_NE(e.find("rep2.csv:3: x_w: not finite"), std::string::npos) << e;
  const std::string u = error_of([&] {
    eval::parse_marks_csv(std::string(kHeader) + "\n" + row(1, 1, 1.0, "inf"), "rep3.csv");
  });
  EXPECT_NE(u.find("rep3.csv:2: u_y_w: not finite"), std::string::npos) << u;
}

TEST(TypeAInput, FewerThanTwoRepetitions) {
  const std::vector<eval::MarksRecording> one = {
      eval::parse_marks_csv(std::string(kHeader) + "\n" + row(1, 1, 1.0), "rep1.csv")};
  const std::string e = error_of([&] { eval::evaluate_type_a(one, world_survey(), "s.json"); });
  EXPECT_NE(e.find("at least 2 repetitions"), std::string::npos) << e;
}

TEST(TypeAInput, MarkNotInTheSurveyNamesFileLineAndSurvey) {
  const std::vector<eval::MarksRecording> two = {
      eval::parse_marks_csv(std::string(kHeader) + "\n" + row(1, 1, 1.0), "rep1.csv"),
      eval::parse_marks_csv(std::string(kHeader) + "\n" + row(1, 1, 1.0) + row(1, 7, 1.0),
                            "rep2.csv")};
  const std::string e = error_of([&] { eval::evaluate_type_a(two, world_survey(), "s.json"); });
  EXPECT_NE(e.find("rep2.csv:3: mark_id: mark 7 is not in the survey s.json"), std::string::npos)
      << e;
}

TEST(TypeAInput, SurveyMustBeInTheWorldFrame) {
  const std::vector<eval::MarksRecording> two = {
      eval::parse_marks_csv(std::string(kHeader) + "\n" + row(1, 1, 1.0), "rep1.csv"),
      eval::parse_marks_csv(std::string(kHeader) + "\n" + row(1, 1, 1.0), "rep2.csv")};
  survey::RigidBodySurvey pylon = world_survey();
  pylon.frame = 'p';
  const std::string e = error_of([&] { eval::evaluate_type_a(two, pylon, "pylon.json"); });
  EXPECT_NE(e.find("pylon.json: frame"), std::string::npos) << e;
}

// Closed form on a hand-made set: values 1.001, 0.999, 1.003 m against 1.0 m.
TEST(TypeAInput, ClosedFormOfThreeRepetitions) {
  std::vector<eval::MarksRecording> reps;
  for (double x : {1.001, 0.999, 1.003})
    reps.push_back(eval::parse_marks_csv(std::string(kHeader) + "\n" + row(1, 1, x), "r.csv"));
  const eval::TypeAResult r = eval::evaluate_type_a(reps, world_survey(), "s.json");
  ASSERT_EQ(r.marks.size(), 1u);
  const eval::AxisTypeA& x = r.marks[0].axis[0];
  EXPECT_NEAR(x.mean_error_m, 0.001, 1e-12);
  EXPECT_NEAR(x.sd_m, 0.002, 1e-12);  // deviations -0, -2, +2 mm: s = sqrt(8/2) mm
  EXPECT_NEAR(x.u_mean_m, 0.002 / std::sqrt(3.0), 1e-12);
  EXPECT_NEAR(x.expanded_m, 2 * 0.002 / std::sqrt(3.0), 1e-12);
  EXPECT_NEAR(x.ratio, 2.0, 1e-9);  // s / u_stated = 2 mm / 1 mm
  // chi-square(2) quantiles in closed form: -2 ln(1 - p).
  EXPECT_NEAR(r.marks[0].ratio_low, std::sqrt(-2 * std::log(1 - 0.025) / 2), 1e-6);
  EXPECT_NEAR(r.marks[0].ratio_high, std::sqrt(-2 * std::log(0.025) / 2), 1e-6);
  EXPECT_FALSE(x.agrees);  // 2.0 > sqrt(ln 40) = 1.921: the stated 1 mm is too small
}

TEST(TypeAInput, ProgramEndToEndOnHostWrittenFiles) {
  const fs::path dir = fs::temp_directory_path() / ("st_eval_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const sim::Scenario scenario = sim::load_scenario(test::scenario_path("static"));
  evalapp::TypeAArgs args;
  for (int i = 0; i < 3; ++i) {
    args.marks_csv.push_back((dir / ("rep" + std::to_string(i) + ".csv")).string());
    std::ofstream(args.marks_csv.back()) << test::simulated_marks_csv(scenario, 500 + i);
  }
  args.survey = (dir / "reference.json").string();
  survey::write_survey(test::true_world_survey(scenario), args.survey);
  args.output = (dir / "result.json").string();
  std::ostringstream out, err;
  EXPECT_EQ(evalapp::run_type_a(args, out, err), 0) << err.str();
  EXPECT_NE(out.str().find("k = 2"), std::string::npos) << out.str();
  std::ifstream result(args.output);
  const nlohmann::json doc = nlohmann::json::parse(result);
  EXPECT_EQ(doc["repetitions"], 3);
  EXPECT_GE(doc["marks"].size(), 3u);
  // A bad repetition stops the program with its name.
  std::ofstream(args.marks_csv[1]) << "trigger_seq [1],mark_id [1]\n1,2\n";
  std::ostringstream out2, err2;
  EXPECT_EQ(evalapp::run_type_a(args, out2, err2), 2);
  EXPECT_NE(err2.str().find(args.marks_csv[1] + ":1: body: missing column"), std::string::npos)
      << err2.str();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace storetrack
