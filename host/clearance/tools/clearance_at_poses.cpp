// storetrack-clearance-at-poses: the minimum distance from the store to every aircraft part of a
// clearance geometry at given store poses T_p_s (the clearance library, no uncertainty). The
// report evaluates the simulator's TRUE poses with it, beside the host's live clearance.
//
//   storetrack-clearance-at-poses GEOMETRY.json < poses > distances.csv
//
// Input: one pose per line, "key x_m y_m z_m rx_rad ry_rad rz_rad" (whitespace separated; key an
// integer, e.g. the trigger_seq; r the rotation vector of R_p_s). Output: CSV
// "key,part,part_name,distance_m,penetration", one row per pose and aircraft part.
// Exit codes: 0 ok, 2 bad arguments, geometry or input line (named).
#include <cstdio>
#include <exception>
#include <iostream>
#include <sstream>
#include <string>

#include "storetrack/clearance/clearance.hpp"

namespace {

namespace cl = storetrack::clearance;
namespace geo = storetrack::geometry;

// One input line into its key and pose; false (with `why`) when it does not parse.
bool parse_pose(const std::string& line, long long& key, geo::Transform& T_p_s, std::string& why) {
  std::istringstream in(line);
  double v[6];
  if (!(in >> key >> v[0] >> v[1] >> v[2] >> v[3] >> v[4] >> v[5])) {
    why = "expected \"key x_m y_m z_m rx_rad ry_rad rz_rad\"";
    return false;
  }
  if (std::string rest; in >> rest) {
    why = "unexpected '" + rest + "' after the pose";
    return false;
  }
  T_p_s = geo::Transform::Identity();
  T_p_s.translation() = geo::Vec3(v[0], v[1], v[2]);
  T_p_s.linear() = geo::rotation_from_rotvec(geo::Vec3(v[3], v[4], v[5]));
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2 || std::string(argv[1]) == "-h" || std::string(argv[1]) == "--help") {
    std::fprintf(stderr, "usage: storetrack-clearance-at-poses GEOMETRY.json < poses > csv\n");
    return argc == 2 ? 0 : 2;
  }
  try {
    cl::ClearanceModel model = cl::ClearanceModel::load(argv[1]);
    std::printf("key,part,part_name,distance_m,penetration\n");
    std::string line;
    for (long long line_number = 1; std::getline(std::cin, line); ++line_number) {
      if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
      long long key = 0;
      geo::Transform T_p_s;
      std::string why;
      if (!parse_pose(line, key, T_p_s, why)) {
        std::fprintf(stderr, "storetrack-clearance-at-poses: stdin line %lld: %s\n", line_number,
                     why.c_str());
        return 2;
      }
      const auto parts = model.evaluate(T_p_s, geo::Mat6::Zero());
      for (std::size_t i = 0; i < parts.size(); ++i)
        std::printf("%lld,%zu,%s,%.9f,%d\n", key, i, std::string(parts[i].part).c_str(),
                    parts[i].distance_m, parts[i].penetration ? 1 : 0);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "storetrack-clearance-at-poses: %s: %s\n", argv[1], e.what());
    return 2;
  }
  return 0;
}
