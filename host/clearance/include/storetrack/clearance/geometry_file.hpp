// The clearance geometry file: which STL describes each body, in which units and frame, and
// whether it must be closed (docs/clearance.md, "Files"). Read with the tree's strict JSON reader:
// every refusal names the file and the field (jsonfile::FieldError); the meshes it names are
// refused with MeshError naming the STL file and the triangle.
//
//   {"format": "storetrack-clearance-geometry", "version": 1, "name": "F-16 station 4, GBU",
//    "bodies": [
//      {"name": "store", "stl": "store.stl", "units": "mm", "frame": "store", "closed": true},
//      {"name": "pylon", "stl": "pylon.stl", "units": "m", "frame": "pylon", "closed": true},
//      {"name": "wing", "stl": "wing_lower.stl", "units": "m", "frame": "aircraft",
//       "closed": false, "extent_range_m": [1, 20]}]}
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "storetrack/clearance/mesh.hpp"
#include "storetrack/geometry/transform.hpp"

namespace storetrack::clearance {

enum class BodyFrame : std::uint8_t {
  kStore,     ///< s: a part of the store, posed by T_p_s
  kPylon,     ///< p: an aircraft part given in the pylon frame
  kAircraft,  ///< w: an aircraft part given in the aircraft frame (moved to p by T_p_w)
};

/// Default plausible extent (largest side of the bounding box, m) of any body when the file
/// states none: from a small fin (5 cm) to a wing (100 m). A mesh exported in mm but declared in
/// m (1000x too large) or the reverse falls outside for every real store and aircraft part.
inline constexpr double kDefaultExtentMin_m = 0.05;
inline constexpr double kDefaultExtentMax_m = 100.0;

struct BodyDescription {
  std::string name;
  std::string stl_path;     ///< resolved against the geometry file's folder
  double scale_to_m = 1.0;  ///< "units": "m" -> 1, "mm" -> 0.001
  BodyFrame frame = BodyFrame::kPylon;
  bool closed = false;
  double extent_min_m = kDefaultExtentMin_m;
  double extent_max_m = kDefaultExtentMax_m;
  std::string field;  ///< where it was read ("<file>: bodies[2]"), for messages
};

struct GeometryDescription {
  std::string name;
  std::vector<BodyDescription> bodies;
};

/// Parses a geometry file's text; `file` names it and is the folder STL paths are relative to.
GeometryDescription parse_geometry(const std::string& json_text, const std::string& file);
/// read_text_file + parse_geometry.
GeometryDescription read_geometry(const std::string& path);

/// A body's mesh, checked, in metres, in frame s (store parts) or p (aircraft parts).
struct Body {
  std::string name;
  BodyFrame frame = BodyFrame::kPylon;
  TriangleMesh mesh;
};

/// Reads and checks one body: the STL (read_stl), closedness when required (check_closed), the
/// extent after the unit conversion against [extent_min_m, extent_max_m], then into frame p
/// (aircraft-frame bodies need T_p_w; refused without it).
Body load_body(const BodyDescription& description,
               const std::optional<geometry::Transform>& T_p_w = std::nullopt);

/// The bytes of a file by its path (the geometry file, or an STL path as the geometry resolves
/// it): from disk, or from elsewhere (storetrack-post: a recording's inputs). Throws naming it.
using GeometryFileReader = std::function<std::string(const std::string& path)>;
/// The same as load_body with the STL's bytes through `read`.
Body load_body(const BodyDescription& description, const GeometryFileReader& read,
               const std::optional<geometry::Transform>& T_p_w = std::nullopt);

}  // namespace storetrack::clearance
