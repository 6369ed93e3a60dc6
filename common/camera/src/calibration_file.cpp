// Rig calibration file reader/writer. The format is documented in docs/calibration-file.md;
// keep the two in step. Parsing is strict: a metrology instrument must not silently run on a
// calibration with a typo in it, so unknown keys, wrong shapes and non-physical values are
// errors that name the file, the JSON path and the reason.
#include "storetrack/camera/calibration_file.hpp"

#include <cmath>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>

#include <nlohmann/json.hpp>

#include "storetrack/geometry/symmetric_eigen.hpp"

namespace storetrack::camera {

namespace {

using nlohmann::json;

constexpr const char* kFormatName = "storetrack-rig-calibration";
constexpr int kFormatVersion = 2;  // written; 1 and 2 are read

/// Walks a JSON document keeping the JSON path (RFC 6901 pointer) for error messages.
class Reader {
 public:
  explicit Reader(std::string origin) : origin_(std::move(origin)) {}

  [[noreturn]] void fail(const std::string& path, const std::string& reason) const {
    throw CalibrationFileError(origin_ + ": " + (path.empty() ? std::string("/") : path) + ": " +
                               reason);
  }

  const json& member(const json& obj, const std::string& path, const char* key) const {
    const auto it = obj.find(key);
    if (it == obj.end()) fail(path, std::string("missing required key \"") + key + "\"");
    return *it;
  }

  void expect_object(const json& j, const std::string& path) const {
    if (!j.is_object()) fail(path, std::string("expected an object, got ") + j.type_name());
  }

  void only_keys(const json& obj, const std::string& path,
                 std::initializer_list<const char*> allowed) const {
    for (const auto& [key, value] : obj.items()) {
      (void)value;
      bool ok = key == "comment";
      for (const char* a : allowed)
        ok = ok || key == a;
      if (!ok)
        fail(path + "/" + key,
             "unknown key (typo?); allowed keys are listed in "
             "docs/calibration-file.md");
    }
  }

  double number(const json& j, const std::string& path) const {
    if (!j.is_number()) fail(path, std::string("expected a number, got ") + j.type_name());
    const double v = j.get<double>();
    if (!std::isfinite(v)) fail(path, "number is not finite");
    return v;
  }

  double number(const json& obj, const std::string& path, const char* key) const {
    return number(member(obj, path, key), path + "/" + key);
  }

  int integer(const json& obj, const std::string& path, const char* key, int lo, int hi) const {
    const json& j = member(obj, path, key);
    const std::string p = path + "/" + key;
    if (!j.is_number_integer()) fail(p, std::string("expected an integer, got ") + j.type_name());
    const auto v = j.get<long long>();
    if (v < lo || v > hi)
      fail(p, "value " + std::to_string(v) + " outside [" + std::to_string(lo) + ", " +
                  std::to_string(hi) + "]");
    return static_cast<int>(v);
  }

  std::vector<double> vector(const json& j, const std::string& path, size_t min_size,
                             size_t max_size) const {
    if (!j.is_array()) fail(path, std::string("expected an array, got ") + j.type_name());
    if (j.size() < min_size || j.size() > max_size)
      fail(path,
           "expected " +
               (min_size == max_size ? std::to_string(min_size)
                                     : std::to_string(min_size) + ".." + std::to_string(max_size)) +
               " numbers, got " + std::to_string(j.size()));
    std::vector<double> out;
    for (size_t i = 0; i < j.size(); ++i)
      out.push_back(number(j[i], path + "/" + std::to_string(i)));
    return out;
  }

  /// A covariance: either full rows [[...], ...] (n x n) or {"standard_deviations": [n]}
  /// (uncorrelated). Must be symmetric and positive semi-definite.
  Eigen::MatrixXd covariance(const json& j, const std::string& path, int n) const {
    Eigen::MatrixXd cov = Eigen::MatrixXd::Zero(n, n);
    if (j.is_object()) {
      only_keys(j, path, {"standard_deviations"});
      const auto sd = vector(member(j, path, "standard_deviations"), path + "/standard_deviations",
                             static_cast<size_t>(n), static_cast<size_t>(n));
      for (int i = 0; i < n; ++i) {
        if (sd[static_cast<size_t>(i)] < 0)
          fail(path + "/standard_deviations/" + std::to_string(i), "negative");
        cov(i, i) = sd[static_cast<size_t>(i)] * sd[static_cast<size_t>(i)];
      }
      return cov;
    }
    if (!j.is_array() || j.size() != static_cast<size_t>(n))
      fail(path, "expected a " + std::to_string(n) + "x" + std::to_string(n) +
                     " array of rows or {\"standard_deviations\": [...]}");
    for (int r = 0; r < n; ++r) {
      const auto row = vector(j[static_cast<size_t>(r)], path + "/" + std::to_string(r),
                              static_cast<size_t>(n), static_cast<size_t>(n));
      for (int c = 0; c < n; ++c)
        cov(r, c) = row[static_cast<size_t>(c)];
    }
    check_covariance(cov, path);
    return cov;
  }

  /// Symmetric (relative 1e-9) and positive semi-definite. PSD is judged on the correlation
  /// matrix so that parameters of very different units (px^2 next to rad^2) are held to the
  /// same relative tolerance.
  void check_covariance(const Eigen::MatrixXd& cov, const std::string& path) const {
    const Eigen::Index n = cov.rows();
    for (Eigen::Index r = 0; r < n; ++r)
      if (cov(r, r) < 0)
        fail(path + "/" + std::to_string(r) + "/" + std::to_string(r),
             "covariance is not positive semi-definite (negative variance)");
    for (Eigen::Index r = 0; r < n; ++r)
      for (Eigen::Index c = r + 1; c < n; ++c) {
        const double tol = 1e-9 * std::sqrt(cov(r, r) * cov(c, c)) + 1e-300;
        if (std::abs(cov(r, c) - cov(c, r)) > tol)
          fail(path + "/" + std::to_string(r) + "/" + std::to_string(c),
               "covariance is not symmetric");
      }
    Eigen::VectorXd inv_sd(n);
    for (Eigen::Index r = 0; r < n; ++r)
      inv_sd(r) = cov(r, r) > 0 ? 1.0 / std::sqrt(cov(r, r)) : 0.0;
    for (Eigen::Index r = 0; r < n; ++r)  // a zero variance with a nonzero covariance
      for (Eigen::Index c = 0; c < n; ++c)
        if ((cov(r, r) == 0 || cov(c, c) == 0) && r != c && cov(r, c) != 0)
          fail(path + "/" + std::to_string(r) + "/" + std::to_string(c),
               "covariance is not positive semi-definite (covariance with a zero variance)");
    const Eigen::MatrixXd correlation = inv_sd.asDiagonal() * cov * inv_sd.asDiagonal();
    const Eigen::VectorXd eigenvalues =
        geometry::symmetric_eigen(Eigen::MatrixXd{0.5 * (correlation + correlation.transpose())},
                                  /*with_vectors=*/false)
            .values;
    if (n > 0 && eigenvalues.minCoeff() < -1e-9)
      fail(path,
           "covariance is not positive semi-definite (smallest eigenvalue of the "
           "correlation matrix " +
               std::to_string(eigenvalues.minCoeff()) + ")");
  }

 private:
  std::string origin_;
};

CalibratedCamera parse_camera(const Reader& rd, const json& j, const std::string& path) {
  rd.expect_object(j, path);
  rd.only_keys(j, path,
               {"camera_id", "unit_id", "image_size", "intrinsics", "intrinsic_covariance", "T_c_w",
                "extrinsic_covariance", "exposure_offset_ns", "exposure_offset_sigma_ns"});
  CalibratedCamera cam;
  cam.camera_id = rd.integer(j, path, "camera_id", 0, 255);
  cam.unit_id = rd.integer(j, path, "unit_id", 0, 255);

  Intrinsics in;
  const std::string size_path = path + "/image_size";
  const json& size = rd.member(j, path, "image_size");
  rd.expect_object(size, size_path);
  rd.only_keys(size, size_path, {"width", "height"});
  in.width = rd.integer(size, size_path, "width", 1, 65535);
  in.height = rd.integer(size, size_path, "height", 1, 65535);

  const std::string in_path = path + "/intrinsics";
  const json& ij = rd.member(j, path, "intrinsics");
  rd.expect_object(ij, in_path);
  rd.only_keys(ij, in_path, {"fx", "fy", "cx", "cy", "skew", "distortion"});
  in.fx = rd.number(ij, in_path, "fx");
  in.fy = rd.number(ij, in_path, "fy");
  if (!(in.fx > 0)) rd.fail(in_path + "/fx", "focal length must be > 0");
  if (!(in.fy > 0)) rd.fail(in_path + "/fy", "focal length must be > 0");
  in.cx = rd.number(ij, in_path, "cx");
  in.cy = rd.number(ij, in_path, "cy");
  in.skew = ij.contains("skew") ? rd.number(ij, in_path, "skew") : 0.0;
  // OpenCV accepts 4, 5 or 8 coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]).
  const std::string dist_path = in_path + "/distortion";
  const auto dist = rd.vector(rd.member(ij, in_path, "distortion"), dist_path, 4, 8);
  if (dist.size() == 6 || dist.size() == 7)
    rd.fail(dist_path,
            "expected 4, 5 or 8 coefficients (OpenCV order k1 k2 p1 p2 [k3 [k4 k5 k6]])");
  for (size_t i = 0; i < dist.size(); ++i)
    in.dist[i] = dist[i];
  cam.model = CameraModel(in);

  cam.intrinsic_covariance = rd.covariance(rd.member(j, path, "intrinsic_covariance"),
                                           path + "/intrinsic_covariance", kNumIntrinsics);

  const std::string pose_path = path + "/T_c_w";
  const json& pj = rd.member(j, path, "T_c_w");
  rd.expect_object(pj, pose_path);
  rd.only_keys(pj, pose_path, {"rotation_vector_rad", "translation_m"});
  const auto rv = rd.vector(rd.member(pj, pose_path, "rotation_vector_rad"),
                            pose_path + "/rotation_vector_rad", 3, 3);
  const auto tv =
      rd.vector(rd.member(pj, pose_path, "translation_m"), pose_path + "/translation_m", 3, 3);
  cam.T_c_w = geometry::make_transform(geometry::Vec3(rv[0], rv[1], rv[2]),
                                       geometry::Vec3(tv[0], tv[1], tv[2]));

  cam.extrinsic_covariance =
      rd.covariance(rd.member(j, path, "extrinsic_covariance"), path + "/extrinsic_covariance", 6);

  cam.exposure_offset_ns =
      j.contains("exposure_offset_ns") ? rd.number(j, path, "exposure_offset_ns") : 0.0;
  cam.exposure_offset_sigma_ns =
      j.contains("exposure_offset_sigma_ns") ? rd.number(j, path, "exposure_offset_sigma_ns") : 0.0;
  if (cam.exposure_offset_sigma_ns < 0)
    rd.fail(path + "/exposure_offset_sigma_ns", "standard uncertainty must be >= 0");
  return cam;
}

/// Version 2's top-level "joint_covariance": {"camera_ids": [...], "matrix": rows}, the
/// cameras in the order of /cameras; its diagonal blocks must equal the cameras' blocks.
Eigen::MatrixXd parse_joint_covariance(const Reader& rd, const json& j,
                                       const std::vector<CalibratedCamera>& cameras) {
  const std::string path = "/joint_covariance";
  rd.expect_object(j, path);
  rd.only_keys(j, path, {"camera_ids", "matrix"});
  const std::string ids_path = path + "/camera_ids";
  const auto ids =
      rd.vector(rd.member(j, path, "camera_ids"), ids_path, cameras.size(), cameras.size());
  for (size_t i = 0; i < cameras.size(); ++i)
    if (ids[i] != cameras[i].camera_id)
      rd.fail(ids_path + "/" + std::to_string(i), "expected camera_id " +
                                                      std::to_string(cameras[i].camera_id) +
                                                      " (the cameras in the order of /cameras)");
  const int n = kJointBlockSize * static_cast<int>(cameras.size());
  const std::string matrix_path = path + "/matrix";
  const Eigen::MatrixXd joint = rd.covariance(rd.member(j, path, "matrix"), matrix_path, n);
  // The per-camera blocks are the marginals of the joint: they must agree (a stale block would
  // make a v1 reader of the same file see another calibration).
  const auto check_block = [&](int at, const Eigen::MatrixXd& block, const std::string& name) {
    for (Eigen::Index r = 0; r < block.rows(); ++r)
      for (Eigen::Index c = 0; c < block.cols(); ++c) {
        const double v = joint(at + r, at + c);
        const double tol = 1e-9 * std::sqrt(joint(at + r, at + r) * joint(at + c, at + c)) + 1e-300;
        if (std::abs(v - block(r, c)) > tol)
          rd.fail(matrix_path + "/" + std::to_string(at + r) + "/" + std::to_string(at + c),
                  "differs from " + name + "/" + std::to_string(r) + "/" + std::to_string(c));
      }
  };
  for (size_t i = 0; i < cameras.size(); ++i) {
    const int at = kJointBlockSize * static_cast<int>(i);
    const std::string cam_path = "/cameras/" + std::to_string(i);
    check_block(at, cameras[i].intrinsic_covariance, cam_path + "/intrinsic_covariance");
    check_block(at + kNumIntrinsics, cameras[i].extrinsic_covariance,
                cam_path + "/extrinsic_covariance");
  }
  return joint;
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

}  // namespace

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
  const Reader rd(origin);
  json doc;
  try {
    doc = json::parse(json_text);
  } catch (const json::exception& e) {  // parse_error, or out_of_range for number overflow
    rd.fail("", std::string("JSON syntax error: ") + e.what());
  }
  rd.expect_object(doc, "");
  rd.only_keys(doc, "", {"format", "version", "cameras", "joint_covariance"});
  const json& fmt = rd.member(doc, "", "format");
  if (!fmt.is_string() || fmt.get<std::string>() != kFormatName)
    rd.fail("/format", std::string("expected \"") + kFormatName + "\"");
  const int version = rd.integer(doc, "", "version", 0, 1000000);
  if (version != 1 && version != 2)
    rd.fail("/version", "unsupported version " + std::to_string(version) + " (this reader: 1, 2)");
  const json& cams = rd.member(doc, "", "cameras");
  if (!cams.is_array() || cams.empty()) rd.fail("/cameras", "expected a non-empty array");

  RigCalibration rig;
  std::set<int> ids;
  for (size_t i = 0; i < cams.size(); ++i) {
    const std::string path = "/cameras/" + std::to_string(i);
    rig.cameras.push_back(parse_camera(rd, cams[i], path));
    if (!ids.insert(rig.cameras.back().camera_id).second)
      rd.fail(path + "/camera_id",
              "duplicate camera_id " + std::to_string(rig.cameras.back().camera_id));
  }
  if (doc.contains("joint_covariance")) {
    if (version < 2)
      rd.fail("/joint_covariance", "needs version 2 (version 1 has no cross-camera covariance)");
    rig.joint_covariance = parse_joint_covariance(rd, doc["joint_covariance"], rig.cameras);
  }
  return rig;
}

RigCalibration read_rig_calibration(const std::string& path) {
  std::ifstream file(path, std::ios::binary);
  if (!file) throw CalibrationFileError(path + ": cannot open file");
  std::ostringstream text;
  text << file.rdbuf();
  if (file.bad()) throw CalibrationFileError(path + ": read error");
  return parse_rig_calibration(text.str(), path);
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
    for (double d : in.dist)
      dist.push_back(d);
    c["intrinsics"] = {{"fx", in.fx}, {"fy", in.fy},     {"cx", in.cx},
                       {"cy", in.cy}, {"skew", in.skew}, {"distortion", dist}};
    c["intrinsic_covariance"] = rows(cam.intrinsic_covariance);
    const geometry::Vec3 rv = geometry::rotvec_from_rotation(cam.T_c_w.linear());
    const geometry::Vec3 t = cam.T_c_w.translation();
    c["T_c_w"] = {{"rotation_vector_rad", {rv.x(), rv.y(), rv.z()}},
                  {"translation_m", {t.x(), t.y(), t.z()}}};
    c["extrinsic_covariance"] = rows(cam.extrinsic_covariance);
    c["exposure_offset_ns"] = cam.exposure_offset_ns;
    c["exposure_offset_sigma_ns"] = cam.exposure_offset_sigma_ns;
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
