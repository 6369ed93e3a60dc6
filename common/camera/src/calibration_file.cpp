// Rig calibration file reader/writer. The format is documented in docs/calibration-file.md;
// keep the two in step. Parsing is strict: a metrology instrument must not silently run on a
// calibration with a typo in it, so unknown keys, wrong shapes and non-physical values are
// errors that name the file, the JSON path and the reason.
#include "storetrack/camera/calibration_file.hpp"

#include <cmath>
#include <fstream>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>

#include "storetrack/geometry/symmetric_eigen.hpp"

namespace storetrack::camera {

namespace {

using nlohmann::json;

constexpr const char* kFormatName = "storetrack-rig-calibration";
constexpr int kFormatVersion = 1;

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
  template <int N>
  Eigen::Matrix<double, N, N> covariance(const json& j, const std::string& path) const {
    Eigen::Matrix<double, N, N> cov = Eigen::Matrix<double, N, N>::Zero();
    if (j.is_object()) {
      only_keys(j, path, {"standard_deviations"});
      const auto sd =
          vector(member(j, path, "standard_deviations"), path + "/standard_deviations", N, N);
      for (int i = 0; i < N; ++i) {
        if (sd[i] < 0) fail(path + "/standard_deviations/" + std::to_string(i), "negative");
        cov(i, i) = sd[i] * sd[i];
      }
      return cov;
    }
    if (!j.is_array() || j.size() != static_cast<size_t>(N))
      fail(path, "expected a " + std::to_string(N) + "x" + std::to_string(N) +
                     " array of rows or {\"standard_deviations\": [...]}");
    for (int r = 0; r < N; ++r) {
      const auto row = vector(j[r], path + "/" + std::to_string(r), N, N);
      for (int c = 0; c < N; ++c)
        cov(r, c) = row[c];
    }
    for (int r = 0; r < N; ++r)
      for (int c = r + 1; c < N; ++c) {
        const double tol = 1e-9 * std::sqrt(std::abs(cov(r, r) * cov(c, c))) + 1e-300;
        if (std::abs(cov(r, c) - cov(c, r)) > tol)
          fail(path + "/" + std::to_string(r) + "/" + std::to_string(c),
               "covariance is not symmetric");
      }
    const Eigen::VectorXd eigenvalues =
        geometry::symmetric_eigen(Eigen::MatrixXd{cov}, /*with_vectors=*/false).values;
    const double scale = std::max(eigenvalues.cwiseAbs().maxCoeff(), 1e-300);
    if (eigenvalues.minCoeff() < -1e-9 * scale)
      fail(path, "covariance is not positive semi-definite (smallest eigenvalue " +
                     std::to_string(eigenvalues.minCoeff()) + ")");
    return cov;
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

  cam.intrinsic_covariance = rd.covariance<kNumIntrinsics>(
      rd.member(j, path, "intrinsic_covariance"), path + "/intrinsic_covariance");

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
      rd.covariance<6>(rd.member(j, path, "extrinsic_covariance"), path + "/extrinsic_covariance");

  cam.exposure_offset_ns =
      j.contains("exposure_offset_ns") ? rd.number(j, path, "exposure_offset_ns") : 0.0;
  cam.exposure_offset_sigma_ns =
      j.contains("exposure_offset_sigma_ns") ? rd.number(j, path, "exposure_offset_sigma_ns") : 0.0;
  if (cam.exposure_offset_sigma_ns < 0)
    rd.fail(path + "/exposure_offset_sigma_ns", "standard uncertainty must be >= 0");
  return cam;
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

RigCalibration parse_rig_calibration(const std::string& json_text, const std::string& origin) {
  const Reader rd(origin);
  json doc;
  try {
    doc = json::parse(json_text);
  } catch (const json::exception& e) {  // parse_error, or out_of_range for number overflow
    rd.fail("", std::string("JSON syntax error: ") + e.what());
  }
  rd.expect_object(doc, "");
  rd.only_keys(doc, "", {"format", "version", "cameras"});
  const json& fmt = rd.member(doc, "", "format");
  if (!fmt.is_string() || fmt.get<std::string>() != kFormatName)
    rd.fail("/format", std::string("expected \"") + kFormatName + "\"");
  const int version = rd.integer(doc, "", "version", 0, 1000000);
  if (version != kFormatVersion)
    rd.fail("/version", "unsupported version " + std::to_string(version) +
                            " (this reader: " + std::to_string(kFormatVersion) + ")");
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
