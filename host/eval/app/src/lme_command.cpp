#include "lme_command.hpp"

#include <fmt/format.h>

#include <fstream>

#include "storetrack/survey/scale_bars.hpp"

namespace storetrack::evalapp {
namespace {

nlohmann::json statistics_json(const eval::LmeStatistics& s) {
  return {{"n", s.n},
          {"max_abs_m", s.max_abs_m},
          {"mean_m", s.mean_m},
          {"sd_m", s.sd_m},
          {"u_rms_m", s.u_rms_m},
          {"z_rms", s.z_rms},
          {"z_rms_interval", {s.z_rms_low, s.z_rms_high}},
          {"exceeding_mpe", s.exceeding_mpe}};
}

nlohmann::json vec_json(const geometry::Vec3& v) {
  return {v.x(), v.y(), v.z()};
}

nlohmann::json bar_json(const eval::BarLme& b) {
  nlohmann::json ms = nlohmann::json::array();
  for (const eval::LengthMeasurement& m : b.measurements)
    ms.push_back({{"repetition", m.repetition},
                  {"trigger_seq", m.trigger_seq},
                  {"measured_m", m.measured_m},
                  {"error_m", m.error_m},
                  {"u_m", m.u_m}});
  return {{"id", b.bar.id},
          {"mark_a", b.bar.mark_a},
          {"mark_b", b.bar.mark_b},
          {"length_m", b.bar.length_m},
          {"u_length_m", b.bar.u_length_m},
          {"p_a_w_m", vec_json(b.p_a_w)},
          {"p_b_w_m", vec_json(b.p_b_w)},
          {"repetitions", b.repetitions},
          {"incomplete_exposures", b.incomplete_exposures},
          {"mpe_m", b.mpe_m},
          {"statistics", statistics_json(b.stats)},
          {"measurements", ms}};
}

std::string verdict(const eval::LmeResult& r, int exceeding) {
  if (!r.options.mpe.assessed) return "not assessed";
  return exceeding == 0 ? "pass" : "FAIL";
}

void print_summary(const eval::LmeResult& r, std::ostream& out) {
  const eval::MaximumPermissibleError& mpe = r.options.mpe;
  out << fmt::format(
      "storetrack-eval lme: {} bars, {} repetitions, {} length measurements (VDI/VDE 2634-1; "
      "u: k = 1, {})\n",
      r.bars.size(), r.repetitions.size(), r.overall.n,
      r.full_covariance ? "full mark covariance"
                        : "per-axis mark u only: off-diagonal covariance taken as zero");
  if (mpe.assessed)
    out << (mpe.k > 0 ? fmt::format("MPE = {:.3f} mm + L / {:g}\n", mpe.a_m * 1e3, mpe.k)
                      : fmt::format("MPE = {:.3f} mm\n", mpe.a_m * 1e3));
  out << "per bar [mm] (seed 001's table: LME max, mean, sigma):\n"
         "  bar                 L cal     n   LME max   LME mean  LME sigma   u (RMS)  "
         "RMS(LME/u) [interval]       MPE  verdict\n";
  for (const eval::BarLme& b : r.bars) {
    const eval::LmeStatistics& s = b.stats;
    out << fmt::format(
        "  {:<16} {:>9.3f} {:>5} {:>9.4f} {:>10.4f} {:>10.4f} {:>9.4f}  {:>5.2f} [{:.2f}, {:.2f}] "
        "{:>9}  {}\n",
        b.bar.id, b.bar.length_m * 1e3, s.n, s.max_abs_m * 1e3, s.mean_m * 1e3, s.sd_m * 1e3,
        s.u_rms_m * 1e3, s.z_rms, s.z_rms_low, s.z_rms_high,
        mpe.assessed ? fmt::format("{:.4f}", b.mpe_m * 1e3) : "-", verdict(r, s.exceeding_mpe));
  }
  const eval::LmeStatistics& o = r.overall;
  out << fmt::format(
      "  {:<16} {:>9} {:>5} {:>9.4f} {:>10.4f} {:>10.4f} {:>9.4f}  {:>5.2f} [{:.2f}, {:.2f}] "
      "{:>9}  {}\n",
      "all", "", o.n, o.max_abs_m * 1e3, o.mean_m * 1e3, o.sd_m * 1e3, o.u_rms_m * 1e3, o.z_rms,
      o.z_rms_low, o.z_rms_high, "", verdict(r, o.exceeding_mpe));
  out << "RMS(LME/u): its chi-square interval assumes independent measurements; the exposures of "
         "one repetition share its calibration error (docs/evaluation.md). u "
      << (r.shared_calibration
              ? "has the calibration error the bar's two ends share (--rig)\n"
              : "treats the bar's two ends as independent (no --rig): overstated when the "
                "calibration dominates\n");
  out << "per repetition [mm] (seed 001's Table 5):\n  repetition      n   LME max   LME mean  "
         "LME sigma\n";
  for (size_t i = 0; i < r.repetitions.size(); ++i) {
    const eval::LmeStatistics& s = r.repetitions[i].stats;
    out << fmt::format("  {:>10} {:>6} {:>9.4f} {:>10.4f} {:>10.4f}\n", i + 1, s.n,
                       s.max_abs_m * 1e3, s.mean_m * 1e3, s.sd_m * 1e3);
  }
  if (mpe.assessed)
    out << fmt::format("verdict: {} ({} of {} measurements exceed the MPE)\n",
                       r.pass ? "PASS" : "FAIL", o.exceeding_mpe, o.n);
}

}  // namespace

void add_lme_command(cli::Command& app, LmeArgs& a) {
  cli::Command& sub =
      app.subcommand("lme", "VDI/VDE 2634-1 length measuring error of calibrated scale bars");
  sub.option("marks_csv", a.marks_csv, "The host's --marks-csv, one file per repetition")
      .required()
      .existing_file();
  sub.option("--bars", a.bars, "Scale-bar definition: bar id, marks, calibrated length, u")
      .required()
      .existing_file();
  sub.option("--mpe-a", a.mpe_a_m, "MPE = A + L/K: A [m] (with --mpe-k)").positive();
  sub.option("--mpe-k", a.mpe_k, "MPE = A + L/K: K [1] (with --mpe-a)").positive();
  sub.option("--mpe", a.mpe_m, "A constant MPE [m] (instead of --mpe-a/--mpe-k)").positive();
  sub.option("--min-repetitions", a.options.min_repetitions,
             "Marks CSVs in which every bar must be measured")
      .range(1, 100000)
      .show_default();
  sub.option("--consistency-level", a.options.consistency_level,
             "Two-sided level of the chi-square interval of RMS(LME/u)")
      .range(0.5, 0.9999)
      .show_default();
  sub.option("--rig", a.rig,
             "Rig calibration the host used: u gets the calibration error the ends share "
             "(needs the marks CSV's observation columns)")
      .existing_file();
  sub.option("-o,--output", a.output, "Result JSON to write").required();
  a.command = &sub;
}

int finish_lme_args(LmeArgs& a, std::ostream& err) {
  const bool has_a = a.command->given("--mpe-a"), has_k = a.command->given("--mpe-k"),
             has_c = a.command->given("--mpe");
  if (has_a != has_k || (has_c && (has_a || has_k))) {
    err << "storetrack-eval lme: give --mpe-a with --mpe-k (MPE = A + L/K), or --mpe alone "
           "(a constant MPE)\n";
    return 2;
  }
  a.options.mpe.assessed = has_a || has_c;
  a.options.mpe.a_m = has_c ? a.mpe_m : a.mpe_a_m;
  a.options.mpe.k = has_c ? 0 : a.mpe_k;
  return -1;
}

nlohmann::json lme_json(const eval::LmeResult& r, const LmeArgs& args) {
  nlohmann::json doc;
  doc["format"] = "storetrack-eval-lme";
  doc["version"] = 1;
  doc["method"] =
      "VDI/VDE 2634-1 length measuring error LME = measured - calibrated per bar and exposure; "
      "u^2 = d^T (S_a + S_b) d - 2 (L_a^T d).(L_b^T d) + u_bar^2 (k = 1; L: the ends' loadings "
      "on the rig's calibration factors, the cross term only with a rig)";
  doc["inputs"] = {{"marks_csv", args.marks_csv}, {"bars", args.bars}, {"rig", args.rig}};
  doc["shared_calibration"] = r.shared_calibration;
  const eval::MaximumPermissibleError& mpe = r.options.mpe;
  doc["mpe"] = mpe.assessed ? nlohmann::json{{"a_m", mpe.a_m}, {"k", mpe.k}} : nlohmann::json();
  doc["verdict"] = verdict(r, r.overall.exceeding_mpe);
  doc["full_covariance"] = r.full_covariance;
  doc["consistency_level"] = r.options.consistency_level;
  doc["overall"] = statistics_json(r.overall);
  nlohmann::json bars = nlohmann::json::array();
  for (const eval::BarLme& b : r.bars)
    bars.push_back(bar_json(b));
  doc["bars"] = bars;
  nlohmann::json reps = nlohmann::json::array();
  for (const eval::RepetitionLme& rep : r.repetitions)
    reps.push_back({{"path", rep.path}, {"statistics", statistics_json(rep.stats)}});
  doc["repetitions"] = reps;
  doc["excluded_rows"] = r.excluded_rows;
  return doc;
}

int run_lme(const LmeArgs& args, std::ostream& out, std::ostream& err) {
  eval::LmeResult result;
  try {
    const survey::ScaleBarSet bars = survey::read_scale_bars(args.bars);
    eval::LmeOptions options = args.options;
    if (!args.rig.empty()) options.rig = camera::read_rig_calibration(args.rig);
    std::vector<eval::MarksRecording> recordings;
    for (const std::string& path : args.marks_csv)
      recordings.push_back(eval::read_marks_csv(path));
    result = eval::evaluate_lme(recordings, bars, args.bars, options);
  } catch (const eval::EvalInputError& e) {
    err << "storetrack-eval lme: " << e.what() << "\n";
    return 2;
  } catch (const survey::SurveyFileError& e) {
    err << "storetrack-eval lme: " << e.what() << "\n";
    return 2;
  } catch (const camera::CalibrationFileError& e) {
    err << "storetrack-eval lme: " << e.what() << "\n";
    return 2;
  }
  std::ofstream f(args.output, std::ios::trunc);
  f << lme_json(result, args).dump(2) << "\n";
  f.close();
  if (!f) {
    err << "storetrack-eval lme: " << args.output << ": cannot write the result\n";
    return 1;
  }
  print_summary(result, out);
  out << "result: " << args.output << "\n";
  return 0;
}

}  // namespace storetrack::evalapp
