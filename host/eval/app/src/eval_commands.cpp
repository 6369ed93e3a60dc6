#include "eval_commands.hpp"

#include <fmt/format.h>

#include <fstream>

#include "storetrack/survey/survey.hpp"

namespace storetrack::evalapp {
namespace {

constexpr const char* kAxes[3] = {"x", "y", "z"};

nlohmann::json axis_json(const eval::AxisTypeA& a) {
  return {{"mean_error_m", a.mean_error_m},
          {"sd_m", a.sd_m},
          {"u_mean_m", a.u_mean_m},
          {"expanded_m", a.expanded_m},
          {"u_stated_m", a.u_stated_m},
          {"u_survey_m", a.u_survey_m},
          {"ratio", a.ratio},
          {"agrees", a.agrees}};
}

void print_summary(const eval::TypeAResult& r, std::ostream& out) {
  const double k = r.options.coverage_factor;
  out << fmt::format(
      "storetrack-eval type-a: {} repetitions, {} marks of body '{}' (GUM Type A, k = {:g}; "
      "agreement: s/u_stated in its {:g} % chi-square interval)\n",
      r.repetitions, r.marks.size(), r.options.body, k, 100 * r.options.agreement_level);
  out << "per axis (SisTrO static table) [mm]:\n"
         "  axis  mean error   s (RMS)   s (max)   u_stated (RMS)   marks agreeing\n";
  for (int a = 0; a < 3; ++a) {
    const eval::AxisSummary& s = r.summary[static_cast<size_t>(a)];
    out << fmt::format("  {:>4}  {:>10.3f}  {:>8.3f}  {:>8.3f}  {:>15.3f}   {}/{}\n", kAxes[a],
                       s.mean_error_m * 1e3, s.sd_rms_m * 1e3, s.sd_max_m * 1e3,
                       s.u_stated_rms_m * 1e3, s.agreeing_marks, r.marks.size());
  }
  out << fmt::format(
      "per mark and axis [mm]: mean error +- U (k = {:g}), s, u = s/sqrt(N), u_stated, "
      "s/u_stated [interval]\n",
      k);
  for (const eval::MarkTypeA& m : r.marks) {
    for (int a = 0; a < 3; ++a) {
      const eval::AxisTypeA& x = m.axis[static_cast<size_t>(a)];
      out << fmt::format(
          "  mark {:>4} {} N={:<3}  {:>8.3f} +- {:<7.3f}  s {:>7.3f}  u {:>7.3f}  u_stated "
          "{:>7.3f}  ratio {:.2f} [{:.2f}, {:.2f}] {}\n",
          m.mark_id, kAxes[a], m.repetitions, x.mean_error_m * 1e3, x.expanded_m * 1e3,
          x.sd_m * 1e3, x.u_mean_m * 1e3, x.u_stated_m * 1e3, x.ratio, m.ratio_low, m.ratio_high,
          x.agrees ? "agrees" : "DISAGREES");
    }
  }
  if (!r.marks_with_one_repetition.empty())
    out << fmt::format("marks seen in one repetition only (not evaluated): {}\n",
                       r.marks_with_one_repetition.size());
  if (!r.surveyed_marks_not_seen.empty())
    out << fmt::format("surveyed marks never seen: {}\n", r.surveyed_marks_not_seen.size());
}

}  // namespace

nlohmann::json type_a_json(const eval::TypeAResult& r, const TypeAArgs& args) {
  nlohmann::json doc;
  doc["format"] = "storetrack-eval-type-a";
  doc["version"] = 1;
  doc["method"] = "GUM JCGM 100:2008 sec. 4.2 Type A over repeated static recordings (SisTrO)";
  doc["inputs"] = {{"marks_csv", args.marks_csv}, {"survey", args.survey}};
  doc["body"] = std::string(1, r.options.body);
  doc["coverage_factor"] = r.options.coverage_factor;
  doc["agreement_level"] = r.options.agreement_level;
  doc["repetitions"] = r.repetitions;
  nlohmann::json summary = nlohmann::json::object();
  for (int a = 0; a < 3; ++a) {
    const eval::AxisSummary& s = r.summary[static_cast<size_t>(a)];
    summary[kAxes[a]] = {{"mean_error_m", s.mean_error_m},
                         {"sd_rms_m", s.sd_rms_m},
                         {"sd_max_m", s.sd_max_m},
                         {"u_stated_rms_m", s.u_stated_rms_m},
                         {"agreeing_marks", s.agreeing_marks}};
  }
  doc["summary"] = summary;
  nlohmann::json marks = nlohmann::json::array();
  for (const eval::MarkTypeA& m : r.marks) {
    nlohmann::json jm = {{"mark_id", m.mark_id},
                         {"repetitions", m.repetitions},
                         {"samples", m.samples},
                         {"ratio_interval", {m.ratio_low, m.ratio_high}}};
    for (int a = 0; a < 3; ++a)
      jm[kAxes[a]] = axis_json(m.axis[static_cast<size_t>(a)]);
    marks.push_back(jm);
  }
  doc["marks"] = marks;
  doc["marks_with_one_repetition"] = r.marks_with_one_repetition;
  doc["surveyed_marks_not_seen"] = r.surveyed_marks_not_seen;
  doc["other_body_samples"] = r.other_body_samples;
  doc["excluded_rows"] = r.excluded_rows;
  return doc;
}

int run_type_a(const TypeAArgs& args, std::ostream& out, std::ostream& err) {
  eval::TypeAResult result;
  try {
    const survey::RigidBodySurvey reference = survey::read_survey(args.survey);
    std::vector<eval::MarksRecording> recordings;
    for (const std::string& path : args.marks_csv)
      recordings.push_back(eval::read_marks_csv(path));
    result = eval::evaluate_type_a(recordings, reference, args.survey, args.options);
  } catch (const eval::EvalInputError& e) {
    err << "storetrack-eval type-a: " << e.what() << "\n";
    return 2;
  } catch (const survey::SurveyFileError& e) {
    err << "storetrack-eval type-a: " << e.what() << "\n";
    return 2;
  }
  std::ofstream f(args.output, std::ios::trunc);
  f << type_a_json(result, args).dump(2) << "\n";
  f.close();
  if (!f) {
    err << "storetrack-eval type-a: " << args.output << ": cannot write the result\n";
    return 1;
  }
  print_summary(result, out);
  out << "result: " << args.output << "\n";
  return 0;
}

}  // namespace storetrack::evalapp
