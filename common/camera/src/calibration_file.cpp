// Rig calibration file reader/writer. The format is documented in docs/calibration-file.md;
// keep the two in step. Parsing is strict: a metrology instrument must not silently run on a
// calibration with a typo in it, so unknown keys, wrong shapes and non-physical values are
// errors that name the file, the JSON path and the reason.
#include "storetrack/camera/calibration_file.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <set>
#include <stdexcept>

#include <nlohmann/json.hpp>

#include "storetrack/geometry/symmetric_eigen.hpp"
#include "storetrack/json/strict_reader.hpp"
#include "storetrack/json/text_file.hpp"

namespace storetrack::camera {

namespace {

using nlohmann::json;

constexpr const char* kFormatName = "storetrack-rig-calibration";
constexpr int kFormatVersion = 2;  // written; 1 and 2 are read

using jsonfile::Object;
using jsonfile::Range;
using jsonfile::Value;

std::string index_path(const std::string& path, Eigen::Index r, Eigen::Index c) {
  return path + "[" + std::to_string(r) + "][" + std::to_string(c) + "]";
}

// Every object of the file may carry a "comment" (docs/calibration-file.md).
Object object_of(const Value& v) {
  Object o = v.object();
  o.known({"comment"});
  return o;
}

/// Symmetric (relative 1e-9) and positive semi-definite. PSD is judged on the correlation
/// matrix so that parameters of very different units (px^2 next to rad^2) are held to the same
/// relative tolerance.
void check_covariance(const Eigen::MatrixXd& cov, const Value& v) {
  const auto fail = [&](Eigen::Index r, Eigen::Index c, const std::string& reason) {
    throw jsonfile::FieldError(v.file(), index_path(v.path(), r, c), reason);
  };
  const Eigen::Index n = cov.rows();
  for (Eigen::Index r = 0; r < n; ++r)
    if (cov(r, r) < 0) fail(r, r, "covariance is not positive semi-definite (negative variance)");
  for (Eigen::Index r = 0; r < n; ++r)
    for (Eigen::Index c = r + 1; c < n; ++c) {
      const double tol = 1e-9 * std::sqrt(cov(r, r) * cov(c, c)) + 1e-300;
      if (std::abs(cov(r, c) - cov(c, r)) > tol) fail(r, c, "covariance is not symmetric");
    }
  Eigen::VectorXd inv_sd(n);
  for (Eigen::Index r = 0; r < n; ++r)
    inv_sd(r) = cov(r, r) > 0 ? 1.0 / std::sqrt(cov(r, r)) : 0.0;
  for (Eigen::Index r = 0; r < n; ++r)  // a zero variance with a nonzero covariance
    for (Eigen::Index c = 0; c < n; ++c)
      if ((cov(r, r) == 0 || cov(c, c) == 0) && r != c && cov(r, c) != 0)
        fail(r, c, "covariance is not positive semi-definite (covariance with a zero variance)");
  const Eigen::MatrixXd correlation = inv_sd.asDiagonal() * cov * inv_sd.asDiagonal();
  const Eigen::VectorXd eigenvalues =
      geometry::symmetric_eigen(Eigen::MatrixXd{0.5 * (correlation + correlation.transpose())},
                                /*with_vectors=*/false)
          .values;
  if (n > 0 && eigenvalues.minCoeff() < -1e-9)
    v.fail(
        "covariance is not positive semi-definite (smallest eigenvalue of the correlation "
        "matrix " +
        std::to_string(eigenvalues.minCoeff()) + ")");
}

/// A covariance: either full rows [[...], ...] (n x n) or {"standard_deviations": [n]}
/// (uncorrelated). Must be symmetric and positive semi-definite.
Eigen::MatrixXd covariance(const Value& v, int n) {
  Eigen::MatrixXd cov = Eigen::MatrixXd::Zero(n, n);
  const auto size = static_cast<std::size_t>(n);
  if (v.json().is_object()) {
    Object o = object_of(v);
    const std::vector<Value> sd = o.at("standard_deviations").array(size, size);
    o.finish();
    for (int i = 0; i < n; ++i)
      cov(i, i) = std::pow(sd[static_cast<std::size_t>(i)].number(Range::at_least(0)), 2);
    return cov;
  }
  if (!v.json().is_array() || v.json().size() != size)
    v.fail("expected a " + std::to_string(n) + "x" + std::to_string(n) +
           " array of rows or {\"standard_deviations\": [...]}");
  const std::vector<Value> rows = v.array();
  for (int r = 0; r < n; ++r) {
    const std::vector<double> row = rows[static_cast<std::size_t>(r)].numbers(size);
    for (int c = 0; c < n; ++c)
      cov(r, c) = row[static_cast<std::size_t>(c)];
  }
  check_covariance(cov, v);
  return cov;
}

Intrinsics parse_intrinsics(Object ij, Intrinsics in) {
  in.fx = ij.at("fx").number(Range::above(0));
  in.fy = ij.at("fy").number(Range::above(0));
  in.cx = ij.at("cx").number();
  in.cy = ij.at("cy").number();
  if (const auto skew = ij.find("skew")) in.skew = skew->number();
  in.lens_model = LensModel::kRationalBrown;  // files before the field was added
  if (const auto model = ij.find("model")) {
    const auto lens_model = lens_model_from_name(model->string());
    if (!lens_model)
      model->fail("unknown lens model \"" + model->string() +
                  "\" (expected \"rational-brown\" or \"kannala-brandt\")");
    in.lens_model = *lens_model;
  }
  const Value dist = ij.at("distortion");
  std::vector<Value> coefficients;
  if (in.lens_model == LensModel::kKannalaBrandt) {
    if (!dist.json().is_array() || dist.json().size() != 4)
      dist.fail("expected 4 coefficients for the kannala-brandt model (k1 k2 k3 k4)");
    coefficients = dist.array(4, 4);
  } else {
    // OpenCV accepts 4, 5 or 8 coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]).
    coefficients = dist.array(4, 8);
    if (coefficients.size() == 6 || coefficients.size() == 7)
      dist.fail("expected 4, 5 or 8 coefficients (OpenCV order k1 k2 p1 p2 [k3 [k4 k5 k6]])");
  }
  for (std::size_t i = 0; i < coefficients.size(); ++i)
    in.dist[i] = coefficients[i].number();
  ij.finish();
  return in;
}

/// "observed_region": {"columns": c, "rows": r, "counts": [r rows of c counts]}.
ObservedRegion parse_observed_region(const Value& v) {
  Object j = object_of(v);
  ObservedRegion region;
  region.columns = static_cast<int>(j.at("columns").integer(1, 1024));
  region.rows = static_cast<int>(j.at("rows").integer(1, 1024));
  const Value counts = j.at("counts");
  const auto rows = static_cast<std::size_t>(region.rows);
  const auto columns = static_cast<std::size_t>(region.columns);
  for (const Value& row : counts.array(rows, rows))
    for (const Value& n : row.array(columns, columns))
      region.counts.push_back(static_cast<int>(n.integer(0, std::numeric_limits<int>::max())));
  j.finish();
  return region;
}

/// One check of "model_error" (cross_validation or residual_map): counts consistent, flagged
/// cells [column, row] inside the grid and as many as flagged_cells.
void check_model_error_test(const Value& v, int columns, int rows) {
  Object j = object_of(v);
  j.at("available").boolean();
  j.at("model_error").boolean();
  const auto tested = j.at("tested_cells").integer(0, columns * rows);
  const auto flagged = j.at("flagged_cells").integer(0, tested);
  j.at("allowed_cells").integer(0, columns * rows);
  double p = 1;
  j.get("joint_p_value", p, Range::closed(0, 1));
  const std::vector<Value> cells = j.at("flagged").array();
  if (static_cast<std::int64_t>(cells.size()) != flagged)
    j.at("flagged").fail(std::to_string(cells.size()) + " cells, but flagged_cells is " +
                         std::to_string(flagged));
  for (const Value& cell : cells) {
    const std::vector<Value> cr = cell.array(2, 2);
    cr[0].integer(0, columns - 1);
    cr[1].integer(0, rows - 1);
  }
  j.finish();
}

/// "model_error" (storetrack-calib's cross-validation and residual map, docs/calibration-file.md):
/// checked, not kept (the host does not use it; the report reads it).
void check_model_error(const Value& v) {
  Object j = object_of(v);
  j.at("verdict").non_empty_string();
  j.at("model_error_dominates").boolean();
  double distance_m = 0;
  j.get("cross_validation_distance_m", distance_m, Range::at_least(0));
  const auto columns = static_cast<int>(j.at("columns").integer(1, 1024));
  const auto rows = static_cast<int>(j.at("rows").integer(1, 1024));
  check_model_error_test(j.at("cross_validation"), columns, rows);
  check_model_error_test(j.at("residual_map"), columns, rows);
  j.finish();
}

CalibratedCamera parse_camera(const Value& v, std::map<int, ObservedRegion>& regions) {
  Object j = object_of(v);
  CalibratedCamera cam;
  cam.camera_id = static_cast<int>(j.at("camera_id").integer(0, 255));
  cam.unit_id = static_cast<int>(j.at("unit_id").integer(0, 255));

  Intrinsics in;
  Object size = object_of(j.at("image_size"));
  in.width = static_cast<int>(size.at("width").integer(1, 65535));
  in.height = static_cast<int>(size.at("height").integer(1, 65535));
  size.finish();
  cam.model = CameraModel(parse_intrinsics(object_of(j.at("intrinsics")), in));
  cam.intrinsic_covariance = covariance(j.at("intrinsic_covariance"), kNumIntrinsics);

  Object pose = object_of(j.at("T_c_w"));
  const std::vector<double> rv = pose.at("rotation_vector_rad").numbers(3);
  const std::vector<double> tv = pose.at("translation_m").numbers(3);
  pose.finish();
  cam.T_c_w = geometry::make_transform(geometry::Vec3(rv[0], rv[1], rv[2]),
                                       geometry::Vec3(tv[0], tv[1], tv[2]));
  cam.extrinsic_covariance = covariance(j.at("extrinsic_covariance"), 6);
  j.get("exposure_offset_ns", cam.exposure_offset_ns);
  j.get("exposure_offset_sigma_ns", cam.exposure_offset_sigma_ns, Range::at_least(0));
  if (const auto region = j.find("observed_region"))
    regions[cam.camera_id] = parse_observed_region(*region);
  if (const auto model_error = j.find("model_error")) check_model_error(*model_error);
  j.finish();
  return cam;
}

/// Version 2's top-level "joint_covariance": {"camera_ids": [...], "matrix": rows}, the
/// cameras in the order of "cameras"; its diagonal blocks must equal the cameras' blocks.
Eigen::MatrixXd parse_joint_covariance(const Value& v,
                                       const std::vector<CalibratedCamera>& cameras) {
  Object j = object_of(v);
  const std::vector<Value> ids = j.at("camera_ids").array(cameras.size(), cameras.size());
  for (std::size_t i = 0; i < cameras.size(); ++i)
    if (ids[i].integer(0, 255) != cameras[i].camera_id)
      ids[i].fail("expected camera_id " + std::to_string(cameras[i].camera_id) +
                  " (the cameras in the order of \"cameras\")");
  const int n = kJointBlockSize * static_cast<int>(cameras.size());
  const Value matrix = j.at("matrix");
  const Eigen::MatrixXd joint = covariance(matrix, n);
  j.finish();
  // The per-camera blocks are the marginals of the joint: they must agree (a stale block would
  // make a v1 reader of the same file see another calibration).
  const auto check_block = [&](int at, const Eigen::MatrixXd& block, const std::string& name) {
    for (Eigen::Index r = 0; r < block.rows(); ++r)
      for (Eigen::Index c = 0; c < block.cols(); ++c) {
        const double x = joint(at + r, at + c);
        const double tol = 1e-9 * std::sqrt(joint(at + r, at + r) * joint(at + c, at + c)) + 1e-300;
        if (std::abs(x - block(r, c)) > tol)
          throw jsonfile::FieldError(matrix.file(), index_path(matrix.path(), at + r, at + c),
                                     "differs from " + index_path(name, r, c));
      }
  };
  for (std::size_t i = 0; i < cameras.size(); ++i) {
    const int at = kJointBlockSize * static_cast<int>(i);
    const std::string cam_path = "cameras[" + std::to_string(i) + "]";
    check_block(at, cameras[i].intrinsic_covariance, cam_path + ".intrinsic_covariance");
    check_block(at + kNumIntrinsics, cameras[i].extrinsic_covariance,
                cam_path + ".extrinsic_covariance");
  }
  return joint;
}

RigCalibration read_calibration_document(const Value& root) {
  Object doc = object_of(root);
  if (const Value fmt = doc.at("format"); fmt.json() != kFormatName)
    fmt.fail(std::string("expected \"") + kFormatName + "\"");
  const Value version_value = doc.at("version");
  const auto version = version_value.integer(0, 1000000);
  if (version != 1 && version != 2)
    version_value.fail("unsupported version " + std::to_string(version) + " (this reader: 1, 2)");
  RigCalibration rig;
  std::set<int> ids;
  for (const Value& c : doc.at("cameras").array(1, std::numeric_limits<std::size_t>::max())) {
    rig.cameras.push_back(parse_camera(c, rig.observed_regions));
    if (!ids.insert(rig.cameras.back().camera_id).second)
      c.fail_member("camera_id",
                    "duplicate camera_id " + std::to_string(rig.cameras.back().camera_id));
  }
  if (const auto joint = doc.find("joint_covariance")) {
    if (version < 2) joint->fail("needs version 2 (version 1 has no cross-camera covariance)");
    rig.joint_covariance = parse_joint_covariance(*joint, rig.cameras);
  }
  doc.finish();
  return rig;
}

template <typename Derived>
json rows(const Eigen::MatrixBase<Derived>& m) {
  json out = json::array();
  for (int r = 0; r < m.rows(); ++r) {
    json row = json::array();
    for (int c = 0; c < m.cols(); ++c)
      row.push_back(m(r, c));
    out.push_back(row);
  }
  return out;
}

json region_json(const ObservedRegion& region) {
  json counts = json::array();
  for (int r = 0; r < region.rows; ++r) {
    const auto begin = region.counts.begin() + r * region.columns;
    counts.push_back(std::vector<int>(begin, begin + region.columns));
  }
  return {{"columns", region.columns}, {"rows", region.rows}, {"counts", counts}};
}

}  // namespace

int ObservedRegion::cell_of(const Eigen::Vector2d& pixel, int width, int height) const {
  // Pixel centres at integers: the image spans [-0.5, width - 0.5).
  const double x = (pixel.x() + 0.5) / width, y = (pixel.y() + 0.5) / height;
  if (!(x >= 0 && x < 1 && y >= 0 && y < 1)) return -1;
  return static_cast<int>(y * rows) * columns + static_cast<int>(x * columns);
}

bool ObservedRegion::contains(const Eigen::Vector2d& pixel, int width, int height,
                              int min_points) const {
  const int cell = cell_of(pixel, width, height);
  return cell >= 0 && static_cast<std::size_t>(cell) < counts.size() &&
         counts[static_cast<std::size_t>(cell)] >= std::max(1, min_points);
}

ObservedRegion observed_region_of(const std::vector<Eigen::Vector2d>& pixels, int width, int height,
                                  int columns, int rows) {
  ObservedRegion region;
  region.columns = columns;
  region.rows = rows;
  region.counts.assign(static_cast<std::size_t>(columns * rows), 0);
  for (const Eigen::Vector2d& pixel : pixels)
    if (const int cell = region.cell_of(pixel, width, height); cell >= 0)
      ++region.counts[static_cast<std::size_t>(cell)];
  return region;
}

const CalibratedCamera* RigCalibration::find(int camera_id) const {
  for (const auto& cam : cameras)
    if (cam.camera_id == camera_id) return &cam;
  return nullptr;
}

Eigen::MatrixXd RigCalibration::full_joint_covariance() const {
  if (joint_covariance.size() > 0) return joint_covariance;
  const Eigen::Index n = kJointBlockSize * static_cast<Eigen::Index>(cameras.size());
  Eigen::MatrixXd joint = Eigen::MatrixXd::Zero(n, n);
  for (size_t i = 0; i < cameras.size(); ++i) {
    const Eigen::Index at = kJointBlockSize * static_cast<Eigen::Index>(i);
    joint.block<kNumIntrinsics, kNumIntrinsics>(at, at) = cameras[i].intrinsic_covariance;
    joint.block<6, 6>(at + kNumIntrinsics, at + kNumIntrinsics) = cameras[i].extrinsic_covariance;
  }
  return joint;
}

bool RigCalibration::has_cross_covariance() const {
  if (joint_covariance.size() == 0) return false;
  Eigen::MatrixXd off = joint_covariance;
  for (size_t i = 0; i < cameras.size(); ++i) {
    const Eigen::Index at = kJointBlockSize * static_cast<Eigen::Index>(i);
    off.block<kNumIntrinsics, kNumIntrinsics>(at, at).setZero();
    off.block<6, 6>(at + kNumIntrinsics, at + kNumIntrinsics).setZero();
  }
  return !off.isZero(0.0);
}

void set_joint_covariance(RigCalibration& rig, const Eigen::MatrixXd& joint) {
  const Eigen::Index n = kJointBlockSize * static_cast<Eigen::Index>(rig.cameras.size());
  if (joint.rows() != n || joint.cols() != n)
    throw std::invalid_argument("set_joint_covariance: expected " + std::to_string(n) + "x" +
                                std::to_string(n) + ", got " + std::to_string(joint.rows()) + "x" +
                                std::to_string(joint.cols()));
  rig.joint_covariance = joint;
  for (size_t i = 0; i < rig.cameras.size(); ++i) {
    const Eigen::Index at = kJointBlockSize * static_cast<Eigen::Index>(i);
    rig.cameras[i].intrinsic_covariance = joint.block<kNumIntrinsics, kNumIntrinsics>(at, at);
    rig.cameras[i].extrinsic_covariance =
        joint.block<6, 6>(at + kNumIntrinsics, at + kNumIntrinsics);
  }
}

RigCalibration parse_rig_calibration(const std::string& json_text, const std::string& origin) {
  try {
    const jsonfile::Document doc = jsonfile::Document::parse(json_text, origin);
    return read_calibration_document(doc.root());
  } catch (const jsonfile::FieldError& e) {
    throw CalibrationFileError(e.what());
  }
}

RigCalibration read_rig_calibration(const std::string& path) {
  std::string text;
  try {
    text = jsonfile::read_text_file(path);
  } catch (const jsonfile::FileReadError& e) {
    throw CalibrationFileError(e.what());
  }
  return parse_rig_calibration(text, path);
}

std::string format_rig_calibration(const RigCalibration& rig) {
  json doc;
  doc["format"] = kFormatName;
  doc["version"] = kFormatVersion;
  doc["cameras"] = json::array();
  for (const auto& cam : rig.cameras) {
    const Intrinsics& in = cam.model.intrinsics();
    json c;
    c["camera_id"] = cam.camera_id;
    c["unit_id"] = cam.unit_id;
    c["image_size"] = {{"width", in.width}, {"height", in.height}};
    json dist = json::array();
    for (int i = 0; i < lens_coefficient_count(in.lens_model); ++i)
      dist.push_back(in.dist[static_cast<std::size_t>(i)]);
    c["intrinsics"] = {{"model", lens_model_name(in.lens_model)},
                       {"fx", in.fx},
                       {"fy", in.fy},
                       {"cx", in.cx},
                       {"cy", in.cy},
                       {"skew", in.skew},
                       {"distortion", dist}};
    c["intrinsic_covariance"] = rows(cam.intrinsic_covariance);
    const geometry::Vec3 rv = geometry::rotvec_from_rotation(cam.T_c_w.linear());
    const geometry::Vec3 t = cam.T_c_w.translation();
    c["T_c_w"] = {{"rotation_vector_rad", {rv.x(), rv.y(), rv.z()}},
                  {"translation_m", {t.x(), t.y(), t.z()}}};
    c["extrinsic_covariance"] = rows(cam.extrinsic_covariance);
    c["exposure_offset_ns"] = cam.exposure_offset_ns;
    c["exposure_offset_sigma_ns"] = cam.exposure_offset_sigma_ns;
    if (const auto region = rig.observed_regions.find(cam.camera_id);
        region != rig.observed_regions.end()) {
      if (region->second.counts.size() !=
          static_cast<std::size_t>(region->second.columns * region->second.rows))
        throw CalibrationFileError("observed_region of camera " + std::to_string(cam.camera_id) +
                                   ": counts do not match columns x rows");
      c["observed_region"] = region_json(region->second);
    }
    doc["cameras"].push_back(c);
  }
  if (rig.joint_covariance.size() > 0) {
    const Eigen::Index n = kJointBlockSize * static_cast<Eigen::Index>(rig.cameras.size());
    if (rig.joint_covariance.rows() != n || rig.joint_covariance.cols() != n)
      throw CalibrationFileError("joint_covariance: expected " + std::to_string(n) + "x" +
                                 std::to_string(n) + " for " + std::to_string(rig.cameras.size()) +
                                 " cameras");
    json ids = json::array();
    for (const auto& cam : rig.cameras)
      ids.push_back(cam.camera_id);
    doc["joint_covariance"] = {{"camera_ids", ids}, {"matrix", rows(rig.joint_covariance)}};
  }
  return doc.dump(2) + "\n";
}

void write_rig_calibration(const RigCalibration& rig, const std::string& path) {
  const std::string text = format_rig_calibration(rig);
  std::ofstream file(path, std::ios::binary | std::ios::trunc);
  if (!file) throw CalibrationFileError(path + ": cannot open for writing");
  file << text;
  file.flush();
  if (!file) throw CalibrationFileError(path + ": write error");
}

}  // namespace storetrack::camera
