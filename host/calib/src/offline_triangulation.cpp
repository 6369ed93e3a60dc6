// storetrack-calib triangulate's parts: the pixel-observation CSV, the host's triangulation
// and calibration loadings per (exposure, mark), the marks CSV.
#include "storetrack/calib/offline_triangulation.hpp"

#include <charconv>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>
#include <tuple>

#include "storetrack/calib/intrinsic_calibration.hpp"  // CalibrationError
#include "storetrack/csv/fields.hpp"
#include "storetrack/triangulate/triangulate.hpp"
#include "storetrack/uncertainty/calibration_factors.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"

namespace storetrack::calib {
namespace {

enum Column { kExposure, kTime, kCamera, kMark, kU, kV, kSigma, kCovUU, kCovUV, kCovVV, kCount };
constexpr const char* kNames[kCount] = {"exposure", "time_ns", "camera_id", "mark_id", "u",
                                        "v",        "sigma",   "cov_uu",    "cov_uv",  "cov_vv"};

[[noreturn]] void fail(const std::string& origin, int line, const std::string& field,
                       const std::string& why) {
  throw ObservationFileError(origin + ":" + std::to_string(line) + ": " + field + ": " + why);
}

/// Header cell name without its unit: "u [px]" -> "u".
std::string column_name(const std::string& cell) {
  return csv::trim(cell.substr(0, cell.find('[')));
}

struct Cells {
  const std::vector<std::string>& cells;
  const std::array<int, kCount>& index;
  const std::string& origin;
  int line;

  bool has(Column c) const { return index[c] >= 0; }
  std::string text(Column c) const { return csv::trim(cells[static_cast<size_t>(index[c])]); }
  long long integer(Column c, long long lo, long long hi) const {
    const std::string t = text(c);
    long long v = 0;
    const auto [end, ec] = std::from_chars(t.data(), t.data() + t.size(), v);
    if (ec != std::errc() || end != t.data() + t.size() || t.empty())
      fail(origin, line, kNames[c], "expected an integer, got '" + t + "'");
    if (v < lo || v > hi) fail(origin, line, kNames[c], "'" + t + "' out of range");
    return v;
  }
  double number(Column c) const {
    const std::string t = text(c);
    double v = 0;
    const auto [end, ec] = std::from_chars(t.data(), t.data() + t.size(), v);
    if (ec != std::errc() || end != t.data() + t.size() || t.empty())
      fail(origin, line, kNames[c], "expected a number, got '" + t + "'");
    if (!std::isfinite(v)) fail(origin, line, kNames[c], "not finite ('" + t + "')");
    return v;
  }
};

std::array<int, kCount> header_columns(const std::string& header, const std::string& origin) {
  std::array<int, kCount> index;
  index.fill(-1);
  const std::vector<std::string> cells = csv::split_fields(header);
  for (size_t i = 0; i < cells.size(); ++i)
    for (int c = 0; c < kCount; ++c)
      if (column_name(cells[i]) == kNames[c]) index[static_cast<size_t>(c)] = static_cast<int>(i);
  for (const Column c : {kExposure, kCamera, kMark, kU, kV})
    if (index[c] < 0) fail(origin, 1, kNames[c], "missing column in the header");
  const int covariance = (index[kCovUU] >= 0) + (index[kCovUV] >= 0) + (index[kCovVV] >= 0);
  if ((index[kSigma] >= 0) == (covariance == 3) || (covariance != 0 && covariance != 3))
    fail(origin, 1, "sigma",
         "expected either a sigma column or the three cov_uu, cov_uv, cov_vv columns");
  return index;
}

Eigen::Matrix2d centroid_covariance(const Cells& row) {
  if (row.has(kSigma)) {
    const double sigma = row.number(kSigma);
    if (!(sigma > 0)) fail(row.origin, row.line, "sigma", "not > 0");
    return sigma * sigma * Eigen::Matrix2d::Identity();
  }
  Eigen::Matrix2d C;
  C << row.number(kCovUU), row.number(kCovUV), row.number(kCovUV), row.number(kCovVV);
  if (!(C(0, 0) > 0 && C(1, 1) > 0 && C.determinant() > 0))
    fail(row.origin, row.line, "cov_uu, cov_uv, cov_vv", "not positive definite");
  return C;
}

/// One (exposure, mark): its observations, in file order.
using MarkKey = std::pair<std::int64_t, int>;

}  // namespace

std::vector<PixelObservation> parse_pixel_observations_csv(const std::string& text,
                                                           const std::string& origin) {
  std::istringstream in(text);
  std::string line_text;
  if (!std::getline(in, line_text)) fail(origin, 1, "header", "empty file");
  const std::array<int, kCount> index = header_columns(line_text, origin);
  int needed = 0;
  for (int i : index)
    needed = std::max(needed, i + 1);
  std::vector<PixelObservation> out;
  std::map<std::tuple<std::int64_t, int, int>, int> seen;  // (exposure, camera, mark) -> line
  for (int line = 2; std::getline(in, line_text); ++line) {
    if (csv::trim(line_text).empty() || csv::trim(line_text)[0] == '#') continue;
    const std::vector<std::string> cells = csv::split_fields(line_text);
    if (static_cast<int>(cells.size()) < needed)
      fail(origin, line, "row",
           std::to_string(cells.size()) + " cells, the header needs " + std::to_string(needed));
    const Cells row{cells, index, origin, line};
    PixelObservation o;
    o.line = line;
    o.exposure = row.integer(kExposure, 0, 0xFFFFFFFFLL);
    if (row.has(kTime)) o.time_ns = row.integer(kTime, 0, INT64_MAX);
    o.camera_id = static_cast<int>(row.integer(kCamera, 0, 255));
    o.mark_id = static_cast<int>(row.integer(kMark, 0, 1000000));
    o.pixel_px = {row.number(kU), row.number(kV)};
    o.covariance_px = centroid_covariance(row);
    const auto [at, fresh] = seen.emplace(std::tuple(o.exposure, o.camera_id, o.mark_id), line);
    if (!fresh)
      fail(origin, line, "mark_id",
           "mark " + std::to_string(o.mark_id) + " of exposure " + std::to_string(o.exposure) +
               " in camera " + std::to_string(o.camera_id) + " is also on line " +
               std::to_string(at->second));
    out.push_back(o);
  }
  if (out.empty()) fail(origin, 2, "rows", "no observations");
  return out;
}

namespace {

/// The host's triangulation of one mark: a first estimate from the centroid weights, then the
/// host's weights at it ((C + the calibration's pixel covariance)^-1) and the calibration's
/// loadings through the estimator's gains (as host/pipeline's exposure processor).
std::optional<TriangulatedMark> triangulate_mark(const camera::RigCalibration& rig,
                                                 const uncertainty::CalibrationFactors& factors,
                                                 const std::vector<const PixelObservation*>& seen,
                                                 const std::vector<int>& slots) {
  std::vector<triangulate::Observation> views;
  for (size_t i = 0; i < seen.size(); ++i) {
    const camera::CalibratedCamera& cam = rig.cameras[static_cast<size_t>(slots[i])];
    triangulate::Observation v;
    v.model = &cam.model;
    v.T_c_w = cam.T_c_w;
    v.pixel_px = seen[i]->pixel_px;
    v.sigma_px = std::sqrt(0.5 * seen[i]->covariance_px.trace());
    geometry::Mat2 W;
    if (uncertainty::inverse_spd<2>(seen[i]->covariance_px, W)) v.information_px = W;
    views.push_back(v);
  }
  triangulate::Result first;
  if (!triangulate::triangulate(views, triangulate::Options{}, first)) return std::nullopt;
  for (size_t i = 0; i < views.size(); ++i) {
    const Eigen::Matrix2d S = seen[i]->covariance_px +
                              uncertainty::pixel_covariance(factors, slots[i], first.jacobians[i]);
    geometry::Mat2 W;
    if (uncertainty::inverse_spd<2>(S, W)) views[i].information_px = W;
  }
  triangulate::Options options;
  options.initial_p_w = first.p_w;
  triangulate::Result tri;
  if (!triangulate::triangulate(views, options, tri)) return std::nullopt;

  TriangulatedMark m;
  m.exposure = seen[0]->exposure;
  m.time_ns = seen[0]->time_ns;
  m.mark_id = seen[0]->mark_id;
  m.p_w = tri.p_w;
  uncertainty::Loadings3 loadings = uncertainty::Loadings3::Zero(3, factors.num_factors());
  Eigen::Matrix3d cov_intrinsic = Eigen::Matrix3d::Zero(), cov_extrinsic = cov_intrinsic;
  for (size_t i = 0; i < views.size(); ++i) {
    // The centroid part through the same gains, with the stated (full) centroid covariance.
    m.cov_centroid += tri.gain[i] * seen[i]->covariance_px * tri.gain[i].transpose();
    uncertainty::add_observation_loadings(factors, slots[i], tri.gain[i], tri.jacobians[i],
                                          loadings, cov_intrinsic, cov_extrinsic);
    m.camera_ids.push_back(seen[i]->camera_id);
    m.pixels_px.push_back(seen[i]->pixel_px);
    m.residuals_px.push_back(tri.residual_px[i]);
    m.sigmas_px.push_back(views[i].sigma_px);
    m.slots.push_back(slots[i]);
    m.gains.push_back(tri.gain[i]);
    m.d_pixel_d_point.push_back(tri.jacobians[i].d_point_world);
  }
  if (factors.coupled()) {
    cov_intrinsic = uncertainty::covariance_of(loadings, factors, uncertainty::Source::kIntrinsic);
    cov_extrinsic = uncertainty::covariance_of(loadings, factors, uncertainty::Source::kExtrinsic);
  }
  m.cov_calibration = cov_intrinsic + cov_extrinsic;
  m.cov_w = m.cov_centroid + m.cov_calibration;
  return m;
}

/// The velocity of every mark from its positions in the neighbouring exposures (central
/// difference, one-sided at the ends; none without times), and the host's sync term with it:
/// camera i saw the mark moved by v dt_i, dt_i its exposure-offset error, so its loading on
/// the camera's sync factor is -K_i (dpixel_i/dp v) sigma_i (host/pipeline's exposure
/// processor). The units' clock errors are not in the CSV: not included.
void add_sync_terms(const uncertainty::CalibrationFactors& factors,
                    std::vector<TriangulatedMark>& marks) {
  std::map<int, std::vector<TriangulatedMark*>> series;  // by mark id, in exposure order
  for (TriangulatedMark& m : marks)
    if (m.time_ns) series[m.mark_id].push_back(&m);
  for (auto& [id, track] : series)
    for (size_t k = 0; k < track.size(); ++k) {
      const TriangulatedMark* before = track[k > 0 ? k - 1 : k];
      const TriangulatedMark* after = track[k + 1 < track.size() ? k + 1 : k];
      const double dt_s = 1e-9 * static_cast<double>(*after->time_ns - *before->time_ns);
      if (!(dt_s > 0)) continue;
      TriangulatedMark& m = *track[k];
      m.velocity_w = (after->p_w - before->p_w) / dt_s;
      uncertainty::Loadings3 loadings = uncertainty::Loadings3::Zero(3, factors.num_factors());
      for (size_t i = 0; i < m.slots.size(); ++i) {
        const auto& cf = factors.camera(m.slots[i]);
        if (cf.sync_column >= 0)
          loadings.col(cf.sync_column) =
              -m.gains[i] * (m.d_pixel_d_point[i] * *m.velocity_w) * cf.sync_sigma_s;
      }
      m.cov_sync = uncertainty::covariance_of(loadings, factors, uncertainty::Source::kSync);
      m.cov_w = m.cov_centroid + m.cov_calibration + m.cov_sync;
    }
}

}  // namespace

OfflineTriangulation triangulate_observations(const camera::RigCalibration& rig,
                                              const std::vector<PixelObservation>& observations,
                                              const std::string& rig_origin,
                                              const std::string& csv_origin) {
  std::map<MarkKey, std::vector<const PixelObservation*>> marks;
  for (const PixelObservation& o : observations) {
    if (rig.find(o.camera_id) == nullptr)
      throw CalibrationError(csv_origin + ":" + std::to_string(o.line) + ": camera_id: camera " +
                             std::to_string(o.camera_id) + " is not in the calibration " +
                             rig_origin);
    marks[{o.exposure, o.mark_id}].push_back(&o);
  }
  const uncertainty::CalibrationFactors factors(rig);
  OfflineTriangulation out;
  for (const auto& [key, seen] : marks) {
    if (seen.size() < 2) {
      ++out.single_camera_marks;
      continue;
    }
    std::vector<int> slots;
    for (const PixelObservation* o : seen)
      slots.push_back(static_cast<int>(rig.find(o->camera_id) - rig.cameras.data()));
    if (auto m = triangulate_mark(rig, factors, seen, slots))
      out.marks.push_back(std::move(*m));
    else
      ++out.failed_marks;
  }
  add_sync_terms(factors, out.marks);
  return out;
}

std::string format_marks_csv(const OfflineTriangulation& result, char body) {
  std::string out =
      "trigger_seq [1],reference_mid_tai_ns [ns],mark_id [1],body [p|s|?],"
      "excluded [0|1],x_w [m],y_w [m],z_w [m],u_x_w [m],u_y_w [m],u_z_w [m],"
      "camera_id [1],u_obs [px],v_obs [px],residual_u [px],residual_v [px],"
      "sigma [px],cov_xy_w [m^2],cov_xz_w [m^2],cov_yz_w [m^2]\n";
  char line[512];
  for (const TriangulatedMark& m : result.marks) {
    const Eigen::Matrix3d& C = m.cov_w;
    for (size_t i = 0; i < m.camera_ids.size(); ++i) {
      std::snprintf(line, sizeof line,
                    "%" PRId64 ",%" PRId64
                    ",%d,%c,0,%.12g,%.12g,%.12g,%.9g,%.9g,%.9g,%d,%.6f,%.6f,%.6f,%.6f,%.6g,%.9g,"
                    "%.9g,%.9g\n",
                    m.exposure, m.time_ns.value_or(0), m.mark_id, body, m.p_w.x(), m.p_w.y(),
                    m.p_w.z(), std::sqrt(C(0, 0)), std::sqrt(C(1, 1)), std::sqrt(C(2, 2)),
                    m.camera_ids[i], m.pixels_px[i].x(), m.pixels_px[i].y(), m.residuals_px[i].x(),
                    m.residuals_px[i].y(), m.sigmas_px[i], C(0, 1), C(0, 2), C(1, 2));
      out += line;
    }
  }
  return out;
}

}  // namespace storetrack::calib
