#include "same_rig.hpp"

#include <algorithm>
#include <stdexcept>
#include <utility>
#include <vector>

namespace storetrack::post {

namespace {

std::vector<std::pair<int, int>> cameras_of(const camera::RigCalibration& rig) {
  std::vector<std::pair<int, int>> ids;
  for (const camera::CalibratedCamera& c : rig.cameras)
    ids.emplace_back(c.unit_id, c.camera_id);
  std::sort(ids.begin(), ids.end());
  return ids;
}

std::string describe(const std::vector<std::pair<int, int>>& ids) {
  // Appended in place: GCC 12 -O3 reports a false -Wstringop-overflow on chained operator+.
  std::string s = std::to_string(ids.size());
  s.append(" camera(s) (unit/camera");
  for (const auto& [unit, cam] : ids)
    s.append(" ").append(std::to_string(unit)).append("/").append(std::to_string(cam));
  s.append(")");
  return s;
}

}  // namespace

void check_same_rig(const camera::RigCalibration& recorded, const std::string& recording_file,
                    const camera::RigCalibration& substitute, const std::string& substitute_path) {
  const auto want = cameras_of(recorded), got = cameras_of(substitute);
  if (want == got) return;
  throw std::runtime_error(substitute_path + ": a calibration of another rig: " + describe(got) +
                           ", where " + recording_file + " was recorded with " + describe(want));
}

}  // namespace storetrack::post
