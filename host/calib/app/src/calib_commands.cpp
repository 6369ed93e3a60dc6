#include "calib_commands.hpp"

#include <cmath>
#include <cstdio>
#include <fstream>

#include <nlohmann/json.hpp>

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

void print_intrinsics(const calib::IntrinsicResult& r, std::ostream& out) {
  const camera::IntrinsicVector v = camera::pack(r.intrinsics);
  static const char* const names[] = {"fx", "fy", "cx", "cy", "skew", "k1", "k2",
                                      "p1", "p2", "k3", "k4", "k5",   "k6"};
  static const char* const units[] = {"px", "px", "px", "px", "px", "", "", "", "", "", "", "", ""};
  for (int i = 0; i < camera::kNumIntrinsics; ++i) {
    const double sigma = std::sqrt(std::max(0.0, r.covariance(i, i)));
    out << "  " << names[i] << " = " << general(v[i]);
    if (sigma > 0)
      out << " +/- " << general(sigma);
    else
      out << " (fixed)";
    out << ' ' << units[i] << "\n";
  }
}

void write_residuals(const calib::IntrinsicResult& r, int camera, const std::string& path) {
  std::ofstream f(path, std::ios::trunc);
  f << "camera,frame,point_id,residual_x_px,residual_y_px,rejected\n";
  for (const auto& p : r.residuals)
    f << camera << ',' << p.frame << ',' << p.point_id << ',' << general(p.residual_px.x()) << ','
      << general(p.residual_px.y()) << ',' << (p.rejected ? 1 : 0) << '\n';
  if (!f.flush()) throw std::runtime_error(path + ": write failed");
}

}  // namespace

int run_detect(const DetectArgs& args, std::ostream& out, std::ostream& err) {
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
  try {
    calib::write_observations_csv(result.set, args.output);
  } catch (const std::exception& e) {
    err << "error: " << e.what() << "\n";
    return 1;
  }
  out << "wrote " << args.output << "\n";
  return 0;
}

std::string intrinsic_calibration_json(const calib::IntrinsicResult& r, int camera_id, int unit_id,
                                       const calib::IntrinsicOptions& options) {
  camera::RigCalibration rig;
  camera::CalibratedCamera cam;
  cam.camera_id = camera_id;
  cam.unit_id = unit_id;
  cam.model = camera::CameraModel(r.intrinsics);
  cam.intrinsic_covariance = r.covariance;
  rig.cameras.push_back(cam);
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
      {"flags",
       {{"fix_aspect_ratio", options.fix_aspect_ratio},
        {"aspect_ratio", options.aspect_ratio},
        {"fix_principal_point", options.fix_principal_point},
        {"zero_tangential", options.zero_tangential},
        {"fix_k1", options.fix_k1},
        {"fix_k2", options.fix_k2},
        {"fix_k3", options.fix_k3},
        {"rational", options.rational}}},
      {"rms_px", r.rms_px},
      {"residual_sigma_px", r.residual_sigma_px},
      {"points_used", r.points_used},
      {"points_rejected", r.points_rejected},
      {"free_parameters", r.free_parameters},
      {"views", views}};
  return doc.dump(2) + "\n";
}

int run_intrinsic(const IntrinsicArgs& args, std::ostream& out, std::ostream& err) {
  calib::IntrinsicResult result;
  try {
    calib::ObservationSet set = calib::read_observations_csv(args.observations);
    if (!args.image_size.empty()) {
      calib::ImageSize size;
      if (!parse_size(args.image_size, size)) {
        err << "error: --image-size: expected WxH, got '" << args.image_size << "'\n";
        return 2;
      }
      set.image_sizes[args.camera] = size;
    }
    result = calib::calibrate_intrinsics(set, args.camera, args.options);
  } catch (const std::exception& e) {  // ObservationFileError, CalibrationError
    err << "error: " << e.what() << "\n";
    return 2;
  }
  out << "intrinsic: camera " << args.camera << ", " << result.views.size() << " views, "
      << result.points_used << " points used, " << result.points_rejected
      << " rejected as outliers\n";
  for (int frame : result.frames_skipped)
    err << "skipped frame " << frame << ": fewer than 4 points of camera " << args.camera << "\n";
  print_intrinsics(result, out);
  out << "  RMS reprojection error " << fixed(result.rms_px, 4) << " px (residual sigma "
      << fixed(result.residual_sigma_px, 4) << " px per axis, " << result.free_parameters
      << " parameters, " << result.iterations << " LM iterations)\n  per view RMS [px]:";
  for (const auto& v : result.views)
    out << ' ' << v.frame << ':' << fixed(v.rms_px, 3);
  out << "\n";
  try {
    std::ofstream f(args.output, std::ios::trunc);
    f << intrinsic_calibration_json(result, args.camera, args.unit_id, args.options);
    if (!f.flush()) throw std::runtime_error(args.output + ": write failed");
    if (!args.residuals_csv.empty()) write_residuals(result, args.camera, args.residuals_csv);
  } catch (const std::exception& e) {
    err << "error: " << e.what() << "\n";
    return 1;
  }
  out << "wrote " << args.output << "\n";
  return 0;
}

}  // namespace storetrack::calibapp
