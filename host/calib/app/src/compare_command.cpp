#include "compare_command.hpp"

#include <cmath>
#include <cstdio>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "command_output.hpp"
#include "storetrack/calib/intrinsic_calibration.hpp"  // CalibrationError
#include "storetrack/calib/observations.hpp"
#include "storetrack/camera/calibration_file.hpp"

namespace storetrack::calibapp {
namespace {

using geometry::Mat3;
using geometry::Vec3;
using nlohmann::json;

json vec(const Vec3& v) {
  return {v.x(), v.y(), v.z()};
}

json sigmas(const Mat3& C) {
  return {std::sqrt(std::max(0.0, C(0, 0))), std::sqrt(std::max(0.0, C(1, 1))),
          std::sqrt(std::max(0.0, C(2, 2)))};
}

json stats_json(const calib::Statistics& s) {
  return {{"count", s.count}, {"rms", s.rms}, {"max", s.max},
          {"p50", s.p50},     {"p95", s.p95}, {"p99", s.p99}};
}

json volume_json(const calib::WorkingVolume& v, const std::array<int, 3>& n) {
  return {{"min_w_m", vec(v.min_w)}, {"max_w_m", vec(v.max_w)}, {"points", {n[0], n[1], n[2]}}};
}

void add_volume_options(cli::Command& sub, VolumeArgs& v, int default_points) {
  v.points_per_axis = default_points;
  sub.option("--distances", v.distances_m,
             "Working distances [m] (depth along each camera's axis), e.g. 1,2,3; default: "
             "0.5, 1, 1.5 x the distance to where the optical axes meet")
      .delimiter(',');
  sub.option("--volume", v.volume, "Working volume x0,x1,y0,y1,z0,z1 [m, world frame]")
      .delimiter(',')
      .expected(6);
  sub.option("--points", v.points_per_axis, "Grid points per axis of the volume").range(1, 201);
  sub.option("--sigma-px", v.sigma_px, "Centroid standard uncertainty per axis [px]").positive();
}

/// Volume options -> library options; throws CalibrationError on an empty box.
std::optional<calib::WorkingVolume> volume_of(const VolumeArgs& v) {
  if (v.volume.empty()) return std::nullopt;
  calib::WorkingVolume out{{v.volume[0], v.volume[2], v.volume[4]},
                           {v.volume[1], v.volume[3], v.volume[5]}};
  if (!(out.min_w.array() <= out.max_w.array()).all())
    throw calib::CalibrationError("--volume: expected x0 <= x1, y0 <= y1, z0 <= z1");
  return out;
}

/// The volume options into the library's options (CompareOptions, UncertaintyMapOptions).
template <class Options>
void set_volume(const VolumeArgs& v, Options& o) {
  o.distances_m = v.distances_m;
  o.volume = volume_of(v);
  o.volume_points = {v.points_per_axis, v.points_per_axis, v.points_per_axis};
  o.sigma_px = v.sigma_px;
}

std::vector<calib::BarSighting> read_bar_sightings(const std::string& path) {
  std::vector<calib::BarSighting> out;
  for (const calib::Observation& o : calib::read_observations_csv(path).observations)
    out.push_back({o.camera, o.point_id, o.pixel});
  return out;
}

void print_comparison(const calib::ComparisonResult& r, const CompareArgs& args,
                      std::ostream& out) {
  out << "compare: a = " << args.a << ", b = " << args.b << "\n";
  out << "working distances [m]:";
  for (double d : r.distances_m)
    out << ' ' << d;
  const Vec3 rv = geometry::rotvec_from_rotation(r.T_b_a.linear());
  out << "\nrigid motion a -> b fitted out: rotation "
      << fmt::format("{:.4f} mdeg, translation {:.3f} mm\n", rv.norm() * 180 / M_PI * 1e3,
                     r.T_b_a.translation().norm() * 1e3);
  out << "projection difference [px]  camera     rms    p50    p95    max   (without the fit: "
         "rms, max)\n";
  for (const auto& c : r.cameras)
    out << fmt::format("                            {:6d} ", c.camera_id)
        << fmt::format("{:7.4f} {:6.4f} {:6.4f} {:6.4f}", c.fitted.rms, c.fitted.p50, c.fitted.p95,
                       c.fitted.max)
        << fmt::format("   ({:.4f}, {:.4f})", c.unfitted.rms, c.unfitted.max)
        << (c.outside_pixels == 0
                ? std::string()
                : fmt::format("   {} of {} grid pixels outside the observed region (max {:.3g} "
                              "px there: extrapolated, left out)",
                              c.outside_pixels, c.pixels.size(), c.fitted_outside.max))
        << "\n";
  out << "triangulated difference |p_b - p_a| over the volume (" << r.valid_points
      << " points seen by >= 2 cameras inside the observed regions, " << r.outside_points
      << " outside the observed region (left out), " << r.unseen_points << " not seen): "
      << fmt::format("rms {:.4f} mm, p95 {:.4f} mm, max {:.4f} mm\n", r.difference_m.rms * 1e3,
                     r.difference_m.p95 * 1e3, r.difference_m.max * 1e3);
  out << fmt::format("predicted standard uncertainty sqrt(trace S) rms: a {:.4f} mm, b {:.4f} mm\n",
                     r.u_a_m.rms * 1e3, r.u_b_m.rms * 1e3);
  out << fmt::format("inconsistent (chi2 of d vs S_a + S_b > {:.2f}): {:.1f} % of the volume\n",
                     r.chi2_threshold, 100 * r.inconsistent_fraction);
  out << fmt::format("joint test over the volume: chi2 {:.1f} for {} dof (p = {:.3g})\n",
                     r.joint_chi2, r.joint_dof, r.joint_p_value);
  for (const auto& b : r.bars) {
    if (!b.valid) {
      out << "scale bar " << b.id << ": not used (" << b.reason << ")\n";
      continue;
    }
    out << "scale bar " << b.id
        << fmt::format(" ({:.2f} mm): error a {:.4f} +/- {:.4f} mm, b {:.4f}", b.length_m * 1e3,
                       b.error_a_m * 1e3, b.u_a_m * 1e3, b.error_b_m * 1e3)
        << fmt::format(" +/- {:.4f} mm (k = 1)\n", b.u_b_m * 1e3);
  }
  out << "verdict: " << r.verdict << "\n";
}

}  // namespace

void add_compare(cli::Command& app, CompareArgs& a) {
  cli::Command& sub = app.subcommand("compare",
                                     "Two calibrations of one rig: projection and triangulated "
                                     "differences against their uncertainties, verdict");
  sub.option("a", a.a, "First rig calibration JSON").required().existing_file();
  sub.option("b", a.b, "Second rig calibration JSON").required().existing_file();
  add_volume_options(sub, a.volume, 11);
  sub.option("--scale-bars", a.scale_bars, "Scale-bar file (storetrack-scale-bars JSON)")
      .existing_file();
  sub.option("--observations", a.observations,
             "Observation CSV of the bars' marks (point_id = mark id), with --scale-bars")
      .existing_file();
  sub.option("--point-false-alarm", a.point_false_alarm,
             "Probability that a grid point of two consistent sets is called inconsistent")
      .range(1e-9, 0.5);
  sub.option("--false-alarm", a.false_alarm,
             "Probability that two consistent sets are called inconsistent (joint test)")
      .range(1e-9, 0.5);
  sub.option("--min-cell-points", a.min_points_per_cell,
             "Points a cell of a file's observed_region needs to count as observed (fewer: the "
             "edge of a board, extrapolation)")
      .range(1, 1000000);
  sub.option("-o,--output", a.output, "Result JSON to write").required();
}

void add_uncertainty_map(cli::Command& app, UncertaintyMapArgs& a) {
  cli::Command& sub = app.subcommand(
      "uncertainty-map", "Predicted 3-D uncertainty of a triangulated mark over the volume");
  sub.option("rig", a.rig, "Rig calibration JSON").required().existing_file();
  add_volume_options(sub, a.volume, 21);
  sub.option("-o,--output", a.output, "Result JSON to write").required();
}

std::string comparison_json(const calib::ComparisonResult& r, const CompareArgs& args) {
  json cameras = json::array();
  for (const auto& c : r.cameras) {
    json pixels = json::array();
    for (const auto& p : c.pixels)
      pixels.push_back({p.x(), p.y()});
    json inside = json::array();
    for (const bool in : c.inside)
      inside.push_back(in);
    cameras.push_back({{"camera_id", c.camera_id},
                       {"columns", c.columns},
                       {"rows", c.rows},
                       {"pixels", pixels},
                       {"difference_px", c.difference_px},
                       {"difference_unfitted_px", c.difference_unfitted_px},
                       {"inside_observed_region", inside},
                       {"outside_pixels", c.outside_pixels},
                       {"fitted_outside_px", stats_json(c.fitted_outside)},
                       {"fitted_px", stats_json(c.fitted)},
                       {"unfitted_px", stats_json(c.unfitted)}});
  }
  json points = json::array();
  for (const auto& p : r.points)
    points.push_back({{"p_w_m", vec(p.p_w)},
                      {"cameras", p.cameras},
                      {"cameras_inside_observed_region", p.cameras_inside},
                      {"outside_observed_region", p.outside},
                      {"valid", p.valid},
                      {"difference_m", vec(p.difference_m)},
                      {"sigma_a_m", sigmas(p.cov_a)},
                      {"sigma_b_m", sigmas(p.cov_b)},
                      {"u_a_m", std::sqrt(p.cov_a.trace())},
                      {"u_b_m", std::sqrt(p.cov_b.trace())},
                      {"chi2", std::isfinite(p.chi2) ? json(p.chi2) : json("inf")},
                      {"inconsistent", p.inconsistent}});
  json bars = json::array();
  for (const auto& b : r.bars)
    bars.push_back({{"id", b.id},
                    {"length_m", b.length_m},
                    {"u_length_m", b.u_length_m},
                    {"valid", b.valid},
                    {"reason", b.reason},
                    {"error_a_m", b.error_a_m},
                    {"error_b_m", b.error_b_m},
                    {"u_a_m", b.u_a_m},
                    {"u_b_m", b.u_b_m}});
  const Vec3 rv = geometry::rotvec_from_rotation(r.T_b_a.linear());
  const int n = args.volume.points_per_axis;
  json doc = {
      {"kind", "storetrack-calib-compare"},
      {"a", args.a},
      {"b", args.b},
      {"sigma_px", args.volume.sigma_px},
      {"min_points_per_cell", args.min_points_per_cell},
      {"distances_m", r.distances_m},
      {"volume", volume_json(r.volume, {n, n, n})},
      {"T_b_a", {{"rotation_vector_rad", vec(rv)}, {"translation_m", vec(r.T_b_a.translation())}}},
      {"cameras", cameras},
      {"volume_points", points},
      {"triangulated",
       {{"difference_m", stats_json(r.difference_m)},
        {"u_a_m", stats_json(r.u_a_m)},
        {"u_b_m", stats_json(r.u_b_m)},
        {"chi2_threshold", r.chi2_threshold},
        {"point_false_alarm", args.point_false_alarm},
        {"inconsistent_fraction", r.inconsistent_fraction},
        {"joint_chi2", r.joint_chi2},
        {"joint_dof", r.joint_dof},
        {"joint_p_value", r.joint_p_value},
        {"false_alarm", args.false_alarm},
        {"valid_points", r.valid_points},
        {"unseen_points", r.unseen_points},
        {"outside_points", r.outside_points}}},
      {"warnings", r.warnings},
      {"bars", bars},
      {"verdict",
       {{"consistent", r.consistent},
        {"better", r.better == '=' ? "neither" : std::string(1, r.better)},
        {"text", r.verdict}}}};
  return doc.dump(1) + "\n";
}

std::string uncertainty_map_json(const calib::UncertaintyMap& m, const UncertaintyMapArgs& args) {
  json points = json::array();
  std::vector<double> u;
  for (const auto& p : m.points) {
    const Mat3 C = p.cov_centroid + p.cov_calibration;
    points.push_back({{"p_w_m", vec(p.p_w)},
                      {"cameras", p.cameras},
                      {"valid", p.valid},
                      {"u_m", std::sqrt(C.trace())},
                      {"u_centroid_m", std::sqrt(p.cov_centroid.trace())},
                      {"u_calibration_m", std::sqrt(p.cov_calibration.trace())},
                      {"sigma_m", sigmas(C)}});
    if (p.valid) u.push_back(std::sqrt(C.trace()));
  }
  const json doc = {{"kind", "storetrack-calib-uncertainty-map"},
                    {"rig", args.rig},
                    {"sigma_px", args.volume.sigma_px},
                    {"covariance_source", m.covariance_source},
                    {"volume", volume_json(m.volume, m.n)},
                    {"u_m", stats_json(calib::statistics_of(u))},
                    {"points", points}};
  return doc.dump(1) + "\n";
}

int run_compare(const CompareArgs& args, std::ostream& out, std::ostream& err) {
  calib::ComparisonResult result;
  try {
    const camera::RigCalibration a = camera::read_rig_calibration(args.a);
    const camera::RigCalibration b = camera::read_rig_calibration(args.b);
    calib::CompareOptions o;
    o.origin_a = args.a;
    o.origin_b = args.b;
    set_volume(args.volume, o);
    o.point_false_alarm = args.point_false_alarm;
    o.false_alarm = args.false_alarm;
    o.min_points_per_cell = args.min_points_per_cell;
    if (args.scale_bars.empty() != args.observations.empty())
      throw calib::CalibrationError(
          "--scale-bars and --observations: give both (the bars and their marks' pixels)");
    std::optional<survey::ScaleBarSet> bars;
    std::vector<calib::BarSighting> sightings;
    if (!args.scale_bars.empty()) {
      bars = survey::read_scale_bars(args.scale_bars);
      sightings = read_bar_sightings(args.observations);
    }
    result = calib::compare_calibrations(a, b, o, bars ? &*bars : nullptr, sightings);
  } catch (const std::exception& e) {
    err << "error: " << e.what() << "\n";
    return 2;
  }
  for (const std::string& warning : result.warnings)
    err << "warning: " << warning << "\n";
  print_comparison(result, args, out);
  return write_outputs(args.output, out, err,
                       [&] { write_text(args.output, comparison_json(result, args)); });
}

int run_uncertainty_map(const UncertaintyMapArgs& args, std::ostream& out, std::ostream& err) {
  calib::UncertaintyMap map;
  try {
    const camera::RigCalibration rig = camera::read_rig_calibration(args.rig);
    calib::UncertaintyMapOptions o;
    o.origin = args.rig;
    set_volume(args.volume, o);
    map = calib::uncertainty_map(rig, o);
  } catch (const std::exception& e) {
    err << "error: " << e.what() << "\n";
    return 2;
  }
  std::vector<double> u, u_cal, u_cen;
  int unseen = 0;
  for (const auto& p : map.points) {
    if (!p.valid) {
      ++unseen;
      continue;
    }
    u.push_back(std::sqrt((p.cov_centroid + p.cov_calibration).trace()));
    u_cal.push_back(std::sqrt(p.cov_calibration.trace()));
    u_cen.push_back(std::sqrt(p.cov_centroid.trace()));
  }
  const auto s = calib::statistics_of(u), sc = calib::statistics_of(u_cal),
             sn = calib::statistics_of(u_cen);
  out << "uncertainty-map: " << args.rig << ", centroid sigma " << args.volume.sigma_px
      << " px, calibration covariance: " << map.covariance_source << "\n";
  out << fmt::format("volume [m, world]: x {:.3f}..{:.3f}, y {:.3f}..", map.volume.min_w.x(),
                     map.volume.max_w.x(), map.volume.min_w.y())
      << fmt::format("{:.3f}, z {:.3f}..{:.3f}", map.volume.max_w.y(), map.volume.min_w.z(),
                     map.volume.max_w.z())
      << "; " << map.points.size() << " points, " << unseen << " seen by fewer than 2 cameras\n";
  out << fmt::format(
             "3-D standard uncertainty sqrt(trace C) [mm]: median {:.4f}, p95 {:.4f}, max {:.4f}\n",
             s.p50 * 1e3, s.p95 * 1e3, s.max * 1e3)
      << fmt::format("  of it calibration: median {:.4f} mm, centroid: median {:.4f} mm\n",
                     sc.p50 * 1e3, sn.p50 * 1e3);
  return write_outputs(args.output, out, err,
                       [&] { write_text(args.output, uncertainty_map_json(map, args)); });
}

}  // namespace storetrack::calibapp
