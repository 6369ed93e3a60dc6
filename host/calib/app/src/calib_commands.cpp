#include "calib_commands.hpp"

#include <cmath>
#include <cstdio>
#include <map>
#include <set>
#include <sstream>
#include <tuple>

#include <nlohmann/json.hpp>

#include "command_output.hpp"
#include "detect_report.hpp"
#include "model_error_output.hpp"
#include "storetrack/camera/calibration_file.hpp"

namespace storetrack::calibapp {
namespace {

std::string fixed(double v, int decimals) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

std::string general(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

bool parse_size(const std::string& text, calib::ImageSize& size) {
  int w = 0, h = 0;
  char x = 0, extra = 0;
  if (std::sscanf(text.c_str(), "%d%c%d%c", &w, &x, &h, &extra) != 3 || x != 'x' || w <= 0 ||
      h <= 0)
    return false;
  size = {w, h};
  return true;
}

void print_intrinsics(const camera::Intrinsics& intrinsics,
                      const camera::IntrinsicCovariance& covariance, std::ostream& out) {
  const camera::IntrinsicVector v = camera::pack(intrinsics);
  static const char* const brown_names[] = {"fx", "fy", "cx", "cy", "skew", "k1", "k2",
                                            "p1", "p2", "k3", "k4", "k5",   "k6"};
  // Kannala-Brandt: k1..k4 in entries 5..8; 9..12 are not parameters of the model.
  static const char* const fisheye_names[] = {"fx", "fy", "cx", "cy", "skew", "k1", "k2",
                                              "k3", "k4", "",   "",   "",     ""};
  const bool fisheye = intrinsics.lens_model == camera::LensModel::kKannalaBrandt;
  const char* const* names = fisheye ? fisheye_names : brown_names;
  out << "  lens model: " << camera::lens_model_name(intrinsics.lens_model) << "\n";
  static const char* const units[] = {"px", "px", "px", "px", "px", "", "", "", "", "", "", "", ""};
  const int count = 5 + camera::lens_coefficient_count(intrinsics.lens_model);
  for (int i = 0; i < count; ++i) {
    const double sigma = std::sqrt(std::max(0.0, covariance(i, i)));
    out << "  " << names[i] << " = " << general(v[i]);
    if (sigma > 0)
      out << " +/- " << general(sigma);
    else
      out << " (fixed)";
    out << ' ' << units[i] << "\n";
  }
}

void write_residual_rows(const std::vector<calib::PointResidual>& residuals, int camera,
                         std::ostream& f) {
  for (const auto& p : residuals)
    f << camera << ',' << p.frame << ',' << p.point_id << ',' << general(p.residual_px.x()) << ','
      << general(p.residual_px.y()) << ',' << (p.rejected ? 1 : 0) << '\n';
}

constexpr const char* kResidualHeader =
    "camera,frame,point_id,residual_x_px,residual_y_px,rejected\n";

void write_residuals(const calib::IntrinsicResult& r, int camera, const std::string& path) {
  std::ostringstream rows;
  rows << kResidualHeader;
  write_residual_rows(r.residuals, camera, rows);
  write_text(path, rows.str());
}

nlohmann::json flags_json(const calib::IntrinsicOptions& options) {
  return {{"fix_aspect_ratio", options.fix_aspect_ratio},
          {"aspect_ratio", options.aspect_ratio},
          {"fix_principal_point", options.fix_principal_point},
          {"zero_tangential", options.zero_tangential},
          {"fix_k1", options.fix_k1},
          {"fix_k2", options.fix_k2},
          {"fix_k3", options.fix_k3},
          {"rational", options.rational},
          {"lens_model", camera::lens_model_name(options.lens_model)},
          {"outlier_false_alarm", options.outlier_false_alarm},
          {"board_deflection", options.board_deflection == calib::BoardDeflection::on    ? "on"
                               : options.board_deflection == calib::BoardDeflection::off ? "off"
                                                                                         : "auto"}};
}

/// The fitted board deflection for the calibration file's comment (docs/calibration-file.md).
nlohmann::json deflection_json(const calib::BoardDeflectionResult& d) {
  nlohmann::json j = {{"model", "mrcal calobject_warp: z = c_x (1 - xn^2) + c_y (1 - yn^2)"},
                      {"fitted", d.fitted},
                      {"reason", d.reason},
                      {"extent_m", {d.x_min, d.x_max, d.y_min, d.y_max}}};
  if (d.fitted) {
    j["c_m"] = {d.c_m.x(), d.c_m.y()};
    j["covariance_m2"] = {{d.covariance(0, 0), d.covariance(0, 1)},
                          {d.covariance(1, 0), d.covariance(1, 1)}};
  }
  return j;
}

/// "board deflection: c_x = ... mm +- ..., c_y = ..., centre depth ... mm" or why not fitted.
void print_deflection(const calib::BoardDeflectionResult& d, std::ostream& out) {
  out << "  board deflection: " << d.reason;
  if (d.fitted) {
    const double depth_sigma =
        std::sqrt(d.covariance(0, 0) + 2 * d.covariance(0, 1) + d.covariance(1, 1));
    out << "; c_x = " << fixed(1e3 * d.c_m.x(), 3) << " +- "
        << fixed(1e3 * std::sqrt(d.covariance(0, 0)), 3)
        << " mm, c_y = " << fixed(1e3 * d.c_m.y(), 3) << " +- "
        << fixed(1e3 * std::sqrt(d.covariance(1, 1)), 3) << " mm (depth at the board's centre "
        << fixed(1e3 * d.c_m.sum(), 3) << " +- " << fixed(1e3 * depth_sigma, 3) << " mm)";
  }
  out << "\n";
}

/// The pixels of `camera`'s points that the fit used (its residuals not rejected), counted on the
/// calibration file's grid: where the fitted model is backed by data.
camera::ObservedRegion used_region(const calib::ObservationSet& set, int camera,
                                   const std::vector<calib::PointResidual>& residuals,
                                   const camera::Intrinsics& in) {
  std::set<std::pair<int, int>> used;  // (frame, point)
  for (const calib::PointResidual& r : residuals)
    if (!r.rejected) used.emplace(r.frame, r.point_id);
  std::vector<Eigen::Vector2d> pixels;
  for (const calib::Observation& o : set.observations)
    if (o.camera == camera && used.contains({o.frame, o.point_id})) pixels.push_back(o.pixel);
  return camera::observed_region_of(pixels, in.width, in.height);
}

}  // namespace

int run_detect(const DetectArgs& args, std::ostream& out, std::ostream& err) {
  if (args.board == "charuco") return run_detect_charuco(args, out, err);
  if (args.board != "chessboard") return run_dot_detect(args, out, err);
  const calib::DetectionResult result =
      calib::detect_chessboards(args.images, args.chessboard, args.camera);
  for (const auto& rejected : result.rejected)
    err << "rejected " << rejected.path << ": " << rejected.reason << "\n";
  out << "detect: " << result.images_used << " of " << args.images.size() << " images used, "
      << result.rejected.size() << " rejected, " << result.set.observations.size() << " corners ("
      << args.chessboard.cols << "x" << args.chessboard.rows << ", square "
      << general(args.chessboard.square_m) << " m)\n";
  if (result.images_used == 0) {
    err << "error: no image gave a board; nothing written\n";
    return 2;
  }
  return write_outputs(args.output, out, err, [&] {
    write_detect_report(args, result, {});
    calib::write_observations_csv(result.set, args.output);
  });
}

std::string intrinsic_calibration_json(const calib::IntrinsicResult& r, int camera_id, int unit_id,
                                       const calib::IntrinsicOptions& options,
                                       const calib::ObservationSet* observations) {
  camera::RigCalibration rig;
  camera::CalibratedCamera cam;
  cam.camera_id = camera_id;
  cam.unit_id = unit_id;
  cam.model = camera::CameraModel(r.intrinsics);
  cam.intrinsic_covariance = r.covariance;
  rig.cameras.push_back(cam);
  if (observations != nullptr)
    rig.observed_regions[camera_id] =
        used_region(*observations, camera_id, r.residuals, r.intrinsics);
  nlohmann::json doc = nlohmann::json::parse(camera::format_rig_calibration(rig));
  nlohmann::json views = nlohmann::json::array();
  for (const auto& v : r.views)
    views.push_back({{"frame", v.frame},
                     {"rms_px", v.rms_px},
                     {"points_used", v.points_used},
                     {"points_rejected", v.points_rejected}});
  doc["cameras"][0]["comment"] = {
      {"produced_by", "storetrack-calib intrinsic"},
      {"extrinsics",
       "NOT calibrated: T_c_w is a placeholder (identity, zero covariance) until the rig and "
       "register steps; do not fly with it"},
      {"flags", flags_json(options)},
      {"rms_px", r.rms_px},
      {"residual_sigma_px", r.residual_sigma_px},
      {"points_used", r.points_used},
      {"points_rejected", r.points_rejected},
      {"free_parameters", r.free_parameters},
      {"board_deflection", deflection_json(r.board_deflection)},
      {"views", views}};
  return doc.dump(2) + "\n";
}

namespace {
/// The views the calibration left out, each named with its reason, on stderr.
void warn_skipped(const std::vector<calib::SkippedView>& skipped, int camera, std::ostream& err) {
  for (const calib::SkippedView& v : skipped)
    err << "warning: camera " << camera << " frame " << v.frame << " skipped: " << v.reason << "\n";
}

std::string skipped_count(const std::vector<calib::SkippedView>& skipped) {
  return skipped.empty() ? "" : ", " + std::to_string(skipped.size()) + " views skipped";
}

std::vector<calib::SkippedView> all_skipped(const calib::RigResult& result) {
  std::vector<calib::SkippedView> all;
  for (const auto& c : result.cameras)
    all.insert(all.end(), c.views_skipped.begin(), c.views_skipped.end());
  return all;
}
}  // namespace

int run_intrinsic(const IntrinsicArgs& args, std::ostream& out, std::ostream& err) {
  calib::IntrinsicResult result;
  calib::ObservationSet set;
  try {
    set = calib::read_observations_csv(args.observations);
    if (!args.image_size.empty()) {
      calib::ImageSize size;
      if (!parse_size(args.image_size, size)) {
        err << "error: --image-size: expected WxH, got '" << args.image_size << "'\n";
        return 2;
      }
      set.image_sizes[args.camera] = size;
    }
    result = calib::calibrate_intrinsics(set, args.camera, args.options);
  } catch (const calib::CalibrationError& e) {  // names the camera; the file is ours to name
    err << "error: " << args.observations << ": " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {  // ObservationFileError: names file, line and field
    err << "error: " << e.what() << "\n";
    return 2;
  }
  out << "intrinsic: camera " << args.camera << ", " << result.views.size() << " views, "
      << result.points_used << " points used, " << result.points_rejected << " rejected as outliers"
      << skipped_count(result.views_skipped) << "\n";
  warn_skipped(result.views_skipped, args.camera, err);
  print_intrinsics(result.intrinsics, result.covariance, out);
  print_deflection(result.board_deflection, out);
  out << "  RMS reprojection error " << fixed(result.rms_px, 4) << " px (residual sigma "
      << fixed(result.residual_sigma_px, 4) << " px per axis, " << result.free_parameters
      << " parameters, " << result.iterations << " LM iterations)\n  per view RMS [px]:";
  for (const auto& v : result.views)
    out << ' ' << v.frame << ':' << fixed(v.rms_px, 3);
  out << "\n";
  std::vector<calib::ModelErrorCheck> checks;
  if (!args.no_model_check) {
    std::vector<int> frames;
    for (const auto& v : result.views)
      frames.push_back(v.frame);
    checks.push_back(calib::check_model_error(set, args.camera, frames, result.residuals,
                                              result.intrinsics.width, result.intrinsics.height,
                                              result.residual_sigma_px, args.options, {}));
    print_model_error(checks, out);
  }
  return write_outputs(args.output, out, err, [&] {
    write_text(args.output,
               with_model_error(intrinsic_calibration_json(result, args.camera, args.unit_id,
                                                           args.options, &set),
                                checks));
    if (!args.residuals_csv.empty()) write_residuals(result, args.camera, args.residuals_csv);
  });
}

namespace {
std::string join_paths(const std::vector<std::string>& paths) {
  std::string joined;
  for (const std::string& p : paths)
    joined += (joined.empty() ? "" : ", ") + p;
  return joined;
}
}  // namespace

calib::ObservationSet merge_observation_files(const std::vector<std::string>& paths) {
  calib::ObservationSet merged;
  std::map<std::tuple<int, int, int>, std::string> origin;  // (camera, frame, point) -> file
  // point -> its first board position and file (one board per calibration)
  std::map<int, std::pair<Eigen::Vector3d, std::string>> board;
  for (const std::string& path : paths) {
    calib::ObservationSet one = calib::read_observations_csv(path);
    for (const calib::Observation& o : one.observations) {
      const auto [at, fresh] = origin.emplace(std::tuple(o.camera, o.frame, o.point_id), path);
      if (!fresh)
        throw calib::ObservationFileError(path + ": camera " + std::to_string(o.camera) +
                                          " frame " + std::to_string(o.frame) + " point " +
                                          std::to_string(o.point_id) + " is also in " + at->second);
      const auto [first, new_point] = board.emplace(o.point_id, std::pair(o.p_board, path));
      const std::string conflict =
          new_point ? ""
                    : calib::board_position_conflict(o.point_id, o.p_board, first->second.first,
                                                     "in " + first->second.second);
      if (!conflict.empty()) throw calib::ObservationFileError(path + ": " + conflict);
      merged.observations.push_back(o);
    }
    for (const auto& [camera, size] : one.image_sizes) {
      const auto [at, fresh] = merged.image_sizes.emplace(camera, size);
      if (!fresh && (at->second.width != size.width || at->second.height != size.height))
        throw calib::ObservationFileError(path + ": image_size of camera " +
                                          std::to_string(camera) + " differs from an earlier file");
    }
    merged.frame_sources.merge(one.frame_sources);  // informative only; first one kept
  }
  return merged;
}

namespace {

void print_rig_camera(const calib::RigCameraResult& c, std::ostream& out) {
  out << "camera " << c.camera_id << (c.camera_id == 0 ? " (reference, S_r)" : "") << ": "
      << c.views.size() << " views, " << c.points_used << " points used, " << c.points_rejected
      << " rejected as outliers, RMS " << fixed(c.rms_px, 4) << " px (own intrinsic fit "
      << fixed(c.start_rms_px, 4) << " px)\n";
  print_intrinsics(c.intrinsics, c.intrinsic_covariance, out);
  if (c.camera_id != 0) {
    const geometry::Vec3 r = geometry::rotvec_from_rotation(c.T_c_r.linear()) * 180 / M_PI;
    const geometry::Vec3 t = c.T_c_r.translation() * 1000;
    const auto sd = [&](int i) { return std::sqrt(std::max(0.0, c.extrinsic_covariance(i, i))); };
    out << "  T_c_r rotation vector [deg]:";
    for (int i = 0; i < 3; ++i)
      out << ' ' << fixed(r[i], 4) << " +/- " << fixed(sd(i) * 180 / M_PI, 4);
    out << "\n  T_c_r translation [mm]:";
    for (int i = 0; i < 3; ++i)
      out << ' ' << fixed(t[i], 3) << " +/- " << fixed(sd(3 + i) * 1000, 3);
    out << "\n  baseline |T| = " << fixed(c.baseline_m * 1000, 3) << " +/- "
        << fixed(c.baseline_sigma_m * 1000, 3) << " mm (" << c.common_views_with_reference
        << " views in common with camera 0)\n";
  }
  out << "  per view RMS [px]:";
  for (const auto& v : c.views)
    out << ' ' << v.frame << ':' << fixed(v.rms_px, 3);
  out << "\n";
}

}  // namespace

std::string rig_calibration_json(const calib::RigResult& r, int unit_id,
                                 const calib::RigOptions& options,
                                 const calib::ObservationSet* observations) {
  camera::RigCalibration rig;
  for (const calib::RigCameraResult& c : r.cameras) {
    camera::CalibratedCamera cam;
    cam.camera_id = c.camera_id;
    cam.unit_id = unit_id;
    cam.model = camera::CameraModel(c.intrinsics);
    cam.intrinsic_covariance = c.intrinsic_covariance;
    cam.T_c_w = c.T_c_r;  // world = S_r until the register step
    cam.extrinsic_covariance = c.extrinsic_covariance;
    rig.cameras.push_back(cam);
    if (observations != nullptr)
      rig.observed_regions[c.camera_id] =
          used_region(*observations, c.camera_id, c.residuals, c.intrinsics);
  }
  // Version 2: the joint covariance (same layout: per camera 13 intrinsics then the left
  // perturbation of T_c_r), cross-camera terms included; the host propagates it.
  camera::set_joint_covariance(rig, r.joint_covariance);
  nlohmann::json doc = nlohmann::json::parse(camera::format_rig_calibration(rig));
  for (size_t i = 0; i < r.cameras.size(); ++i) {
    const calib::RigCameraResult& c = r.cameras[i];
    nlohmann::json views = nlohmann::json::array();
    for (const auto& v : c.views)
      views.push_back({{"frame", v.frame},
                       {"rms_px", v.rms_px},
                       {"points_used", v.points_used},
                       {"points_rejected", v.points_rejected}});
    doc["cameras"][i]["comment"] = {{"produced_by", "storetrack-calib rig"},
                                    {"rms_px", c.rms_px},
                                    {"intrinsic_fit_rms_px", c.start_rms_px},
                                    {"baseline_m", c.baseline_m},
                                    {"baseline_sigma_m", c.baseline_sigma_m},
                                    {"common_views_with_reference", c.common_views_with_reference},
                                    {"points_used", c.points_used},
                                    {"points_rejected", c.points_rejected},
                                    {"views", views}};
  }
  doc["comment"] = {
      {"produced_by", "storetrack-calib rig"},
      {"extrinsics",
       "T_c_w is T_c_r: the world frame is the reference camera's (camera 0, S_r) until the "
       "register step; the extrinsic covariances are relative to S_r (camera 0's is zero by "
       "definition)"},
      {"flags", flags_json(options.intrinsic)},
      {"min_common_views", options.min_common_views},
      {"rms_px", r.rms_px},
      {"residual_sigma_px", r.residual_sigma_px},
      {"points_used", r.points_used},
      {"points_rejected", r.points_rejected},
      {"free_parameters", r.free_parameters},
      {"board_deflection", deflection_json(r.board_deflection)},
      {"frames", r.frames},
      {"joint_covariance",
       "top-level joint_covariance (version 2): board poses marginalised; camera 0's "
       "extrinsic rows are zero (S_r is defined by it)"}};
  return doc.dump(2) + "\n";
}

int run_rig(const RigArgs& args, std::ostream& out, std::ostream& err) {
  calib::RigResult result;
  calib::ObservationSet set;
  try {
    set = merge_observation_files(args.observations);
    for (const std::string& given : args.image_sizes) {
      int camera = -1;
      char eq = 0;
      calib::ImageSize size;
      const auto split = given.find('=');
      if (split == std::string::npos || std::sscanf(given.c_str(), "%d%c", &camera, &eq) != 2 ||
          eq != '=' || camera < 0 || camera > 255 || !parse_size(given.substr(split + 1), size)) {
        err << "error: --image-size: expected CAMERA=WxH, got '" << given << "'\n";
        return 2;
      }
      set.image_sizes[camera] = size;
    }
    result = calib::calibrate_rig(set, args.options);
  } catch (const calib::CalibrationError& e) {  // names the camera; the files are ours to name
    err << "error: " << join_paths(args.observations) << ": " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {  // ObservationFileError: names file, line and field
    err << "error: " << e.what() << "\n";
    return 2;
  }
  out << "rig: " << result.cameras.size() << " cameras, " << result.frames.size()
      << " board poses, " << result.points_used << " points used, " << result.points_rejected
      << " rejected as outliers" << skipped_count(all_skipped(result)) << "\n";
  for (const auto& c : result.cameras) {
    warn_skipped(c.views_skipped, c.camera_id, err);
    print_rig_camera(c, out);
  }
  print_deflection(result.board_deflection, out);
  out << "RMS reprojection error " << fixed(result.rms_px, 4) << " px (residual sigma "
      << fixed(result.residual_sigma_px, 4) << " px per axis, " << result.free_parameters
      << " parameters, " << result.iterations << " LM iterations)\n";
  std::vector<calib::ModelErrorCheck> checks;
  if (!args.no_model_check) {
    for (const auto& c : result.cameras) {
      std::vector<int> frames;
      for (const auto& v : c.views)
        frames.push_back(v.frame);
      checks.push_back(calib::check_model_error(
          set, c.camera_id, frames, c.residuals, c.intrinsics.width, c.intrinsics.height,
          result.residual_sigma_px, args.options.intrinsic, {}));
    }
    print_model_error(checks, out);
  }
  return write_outputs(args.output, out, err, [&] {
    write_text(
        args.output,
        with_model_error(rig_calibration_json(result, args.unit_id, args.options, &set), checks));
    if (!args.residuals_csv.empty()) {
      std::ostringstream rows;
      rows << kResidualHeader;
      for (const auto& c : result.cameras)
        write_residual_rows(c.residuals, c.camera_id, rows);
      write_text(args.residuals_csv, rows.str());
    }
  });
}

}  // namespace storetrack::calibapp
