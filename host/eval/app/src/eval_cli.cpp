#include "eval_cli.hpp"

#include <iostream>

#include "storetrack/cli/command_line.hpp"

namespace storetrack::evalapp {
namespace {

void add_type_a(cli::Command& app, TypeAArgs& a) {
  cli::Command& sub = app.subcommand(
      "type-a", "SisTrO static Type A: repeated static recordings vs total-station coordinates");
  sub.option("marks_csv", a.marks_csv, "The host's --marks-csv, one file per repetition")
      .required()
      .existing_file();
  sub.option("--survey", a.survey, "Reference marks' total-station coordinates (frame w)")
      .required()
      .existing_file();
  sub.option("--body", a.body, "Marks of this body are evaluated (p pylon, s store)")
      .one_of({"p", "s"})
      .show_default();
  sub.option("--coverage-factor", a.options.coverage_factor, "k of U = k u")
      .positive()
      .show_default();
  sub.option("--agreement-level", a.options.agreement_level,
             "Two-sided level of the chi-square interval of s / u_stated")
      .range(0.5, 0.9999)
      .show_default();
  sub.option("-o,--output", a.output, "Result JSON to write").required();
}

void add_noise_floor(cli::Command& app, NoiseFloorArgs& a) {
  cli::Command& sub = app.subcommand(
      "noise-floor", "Seed 002 noise floor: variance and bias errors of one static record");
  sub.option("marks_csv", a.marks_csv, "The host's --marks-csv of a static record")
      .required()
      .existing_file();
  sub.option("--survey", a.survey, "The marks' surveyed coordinates (frame w)")
      .required()
      .existing_file();
  sub.option("--rig", a.rig,
             "Rig calibration the host used: in-plane/out-of-plane axes, stereo angles, the "
             "stated centroid-only u")
      .existing_file();
  sub.option("--body", a.bodies, "Marks of these bodies are evaluated (p, s, ps)")
      .one_of({"p", "s", "ps"})
      .show_default();
  sub.option("--min-samples", a.options.min_samples, "Exposures a record and a mark need")
      .range(3, 1000000)
      .show_default();
  sub.option("--coverage-factor", a.options.coverage_factor, "k of U = k u")
      .positive()
      .show_default();
  sub.option("--agreement-level", a.options.agreement_level,
             "Two-sided level of the chi-square intervals of s / u")
      .range(0.5, 0.9999)
      .show_default();
  sub.option("-o,--output", a.output, "Result JSON to write").required();
}

}  // namespace

int parse_eval_command(int argc, char** argv, EvalCommand& command) {
  cli::Command app{"storetrack-eval: evaluation procedures (docs/evaluation.md)"};
  app.require_subcommand(1);
  add_type_a(app, command.type_a);
  add_lme_command(app, command.lme);
  add_noise_floor(app, command.noise_floor);
  add_pendulum_command(app, command.pendulum);
  if (const int rc = app.parse(argc, argv); rc >= 0) return rc;
  if (app.got_subcommand("type-a")) {
    command.kind = EvalCommand::Kind::kTypeA;
    command.type_a.options.body = command.type_a.body[0];
  }
  if (app.got_subcommand("lme")) {
    command.kind = EvalCommand::Kind::kLme;
    return finish_lme_args(command.lme, std::cerr);
  }
  if (app.got_subcommand("noise-floor")) {
    command.kind = EvalCommand::Kind::kNoiseFloor;
    NoiseFloorArgs& n = command.noise_floor;
    n.options.pylon = n.bodies.find('p') != std::string::npos;
    n.options.store = n.bodies.find('s') != std::string::npos;
  }
  if (app.got_subcommand("pendulum")) {
    command.kind = EvalCommand::Kind::kPendulum;
    finish_pendulum_args(command.pendulum);
  }
  return -1;
}

}  // namespace storetrack::evalapp
