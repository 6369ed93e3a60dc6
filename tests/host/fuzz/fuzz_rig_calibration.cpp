// libFuzzer target: the rig calibration reader (common/camera parse_rig_calibration) on arbitrary
// text. Properties checked (abort when violated), beyond "no crash, no UB":
//  - a refusal is a CalibrationFileError naming the origin; no other exception escapes;
//  - an accepted rig is physical as docs/calibration-file.md requires: at least one camera,
//    unique camera ids, ids in range, finite positive focal lengths, symmetric covariances with
//    non-negative variances, a rotation in T_c_w;
//  - it survives the writer: parse(format(rig)) is accepted and gives the same cameras.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <set>
#include <string>

#include "storetrack/camera/calibration_file.hpp"

namespace {

namespace cam = storetrack::camera;

template <typename M>
bool symmetric_with_nonnegative_diagonal(const M& m) {
  for (int r = 0; r < m.rows(); ++r)
    if (!(m(r, r) >= 0) || !std::isfinite(m(r, r))) return false;  // a variance is >= 0
  for (int r = 0; r < m.rows(); ++r) {
    for (int c = r + 1; c < m.cols(); ++c) {
      const double tol = 1e-9 * std::sqrt(m(r, r) * m(c, c)) + 1e-300;
      if (!(std::abs(m(r, c) - m(c, r)) <= tol)) return false;
    }
  }
  return true;
}

void check_physical(const cam::RigCalibration& rig) {
  if (rig.cameras.empty()) std::abort();
  std::set<int> ids;
  for (const auto& c : rig.cameras) {
    if (c.camera_id < 0 || c.camera_id > 255 || c.unit_id < 0 || c.unit_id > 255) std::abort();
    if (!ids.insert(c.camera_id).second) std::abort();
    const auto& in = c.model.intrinsics();
    if (!(in.fx > 0) || !(in.fy > 0) || !std::isfinite(in.fx) || !std::isfinite(in.fy))
      std::abort();
    if (in.width < 1 || in.height < 1) std::abort();
    if (!symmetric_with_nonnegative_diagonal(c.intrinsic_covariance)) std::abort();
    if (!symmetric_with_nonnegative_diagonal(c.extrinsic_covariance)) std::abort();
    const auto R = c.T_c_w.linear();
    if (!((R * R.transpose() - decltype(R)::Identity()).cwiseAbs().maxCoeff() < 1e-9)) std::abort();
    if (!(c.exposure_offset_sigma_ns >= 0)) std::abort();
  }
}

void check_round_trip(const cam::RigCalibration& rig) {
  cam::RigCalibration again;
  try {
    again = cam::parse_rig_calibration(cam::format_rig_calibration(rig), "round trip");
  } catch (const cam::CalibrationFileError&) {
    std::abort();  // the writer wrote what the reader refuses
  }
  if (again.cameras.size() != rig.cameras.size()) std::abort();
  for (std::size_t i = 0; i < rig.cameras.size(); ++i) {
    const auto& a = rig.cameras[i];
    const auto& b = again.cameras[i];
    if (a.camera_id != b.camera_id || a.unit_id != b.unit_id) std::abort();
    if (a.intrinsic_covariance != b.intrinsic_covariance) std::abort();
    if (a.extrinsic_covariance != b.extrinsic_covariance) std::abort();
    const auto& ia = a.model.intrinsics();
    const auto& ib = b.model.intrinsics();
    if (ia.fx != ib.fx || ia.fy != ib.fy || ia.cx != ib.cx || ia.cy != ib.cy) std::abort();
    if (ia.dist != ib.dist || ia.width != ib.width || ia.height != ib.height) std::abort();
    // T_c_w goes through a rotation vector and back: equal to rounding.
    const double scale = 1.0 + a.T_c_w.translation().cwiseAbs().maxCoeff();
    if (!((a.T_c_w.matrix() - b.T_c_w.matrix()).cwiseAbs().maxCoeff() <= 1e-9 * scale))
      std::abort();
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  cam::RigCalibration rig;
  try {
    rig = cam::parse_rig_calibration(text, "fuzz.json");
  } catch (const cam::CalibrationFileError& e) {
    if (std::string(e.what()).rfind("fuzz.json: ", 0) != 0) std::abort();
    return 0;
  }
  check_physical(rig);
  check_round_trip(rig);
  return 0;
}
