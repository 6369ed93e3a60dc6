#include "storetrack/clearance/geometry_file.hpp"

#include <filesystem>
#include <limits>

#include "storetrack/json/strict_reader.hpp"
#include "storetrack/json/text_file.hpp"

namespace storetrack::clearance {
namespace {

using jsonfile::Object;
using jsonfile::Range;
using jsonfile::Value;

BodyDescription parse_body(const Value& entry, const std::filesystem::path& folder) {
  Object b = entry.object();
  BodyDescription body;
  body.field = entry.file() + ": " + entry.path();
  const Value name = b.at("name");
  body.name = name.non_empty_string();
  // The name is a field of the clearance CSV and of log lines: plain text only.
  if (body.name.find_first_of(",\"\r\n") != std::string::npos)
    name.fail("a body name must not hold a comma, a quote or a line break (it is a CSV field)");
  const std::filesystem::path stl = b.at("stl").non_empty_string();
  body.stl_path = (stl.is_absolute() ? stl : folder / stl).string();
  const Value units = b.at("units");
  const std::string unit_text = units.string();
  if (unit_text == "m") {
    body.scale_to_m = 1.0;
  } else if (unit_text == "mm") {
    body.scale_to_m = 1e-3;
  } else {
    units.fail("unknown units '" + unit_text + "' (expected \"m\" or \"mm\")");
  }
  const Value frame = b.at("frame");
  const std::string frame_text = frame.string();
  if (frame_text == "store") {
    body.frame = BodyFrame::kStore;
  } else if (frame_text == "pylon") {
    body.frame = BodyFrame::kPylon;
  } else if (frame_text == "aircraft") {
    body.frame = BodyFrame::kAircraft;
  } else {
    frame.fail("unknown frame '" + frame_text +
               "' (expected \"store\", \"pylon\" or \"aircraft\")");
  }
  body.closed = b.at("closed").boolean();
  if (const auto range = b.find("extent_range_m")) {
    const std::vector<double> lo_hi = range->numbers(2);
    if (!(lo_hi[0] > 0 && lo_hi[0] < lo_hi[1]))
      range->fail("expected [min, max] with 0 < min < max");
    body.extent_min_m = lo_hi[0];
    body.extent_max_m = lo_hi[1];
  }
  b.finish();
  return body;
}

}  // namespace

GeometryDescription parse_geometry(const std::string& json_text, const std::string& file) {
  const jsonfile::Document doc = jsonfile::Document::parse(json_text, file);
  Object root = doc.root().object();
  if (const Value f = root.at("format"); f.json() != "storetrack-clearance-geometry")
    f.fail("expected \"storetrack-clearance-geometry\"");
  if (const Value v = root.at("version"); v.json() != 1) v.fail("unsupported version (expected 1)");
  GeometryDescription g;
  g.name = root.at("name").non_empty_string();
  const std::filesystem::path folder = std::filesystem::path(file).parent_path();
  bool has_store = false, has_aircraft = false;
  for (const Value& entry : root.at("bodies").array(2, std::numeric_limits<std::size_t>::max())) {
    g.bodies.push_back(parse_body(entry, folder));
    (g.bodies.back().frame == BodyFrame::kStore ? has_store : has_aircraft) = true;
    for (std::size_t i = 0; i + 1 < g.bodies.size(); ++i)
      if (g.bodies[i].name == g.bodies.back().name)
        entry.fail_member(
            "name", "'" + g.bodies.back().name + "' is already the name of " + g.bodies[i].field);
  }
  if (!has_store || !has_aircraft)
    root.value().fail_member("bodies",
                             "needs at least one body in frame \"store\" and one in "
                             "frame \"pylon\" or \"aircraft\"");
  root.finish();
  return g;
}

GeometryDescription read_geometry(const std::string& path) {
  return parse_geometry(jsonfile::read_text_file(path), path);
}

Body load_body(const BodyDescription& description,
               const std::optional<geometry::Transform>& T_p_w) {
  return load_body(description, jsonfile::read_text_file, T_p_w);
}

Body load_body(const BodyDescription& description, const GeometryFileReader& read,
               const std::optional<geometry::Transform>& T_p_w) {
  Body body{description.name, description.frame,
            parse_stl(read(description.stl_path), description.stl_path)};
  if (description.closed) check_closed(body.mesh);
  const double extent_m = largest_extent(body.mesh) * description.scale_to_m;
  if (!(extent_m >= description.extent_min_m && extent_m <= description.extent_max_m))
    throw MeshError(body.mesh.source, std::nullopt,
                    "implausible size: the largest side of its bounding box is " +
                        jsonfile::number_text(extent_m) + " m with the units of " +
                        description.field + ", outside the plausible [" +
                        jsonfile::number_text(description.extent_min_m) + ", " +
                        jsonfile::number_text(description.extent_max_m) +
                        "] m (wrong units? a mesh in mm declared in m is 1000x too large)");
  geometry::Transform T_out_m = geometry::Transform::Identity();
  if (description.frame == BodyFrame::kAircraft) {
    if (!T_p_w)
      throw MeshError(body.mesh.source, std::nullopt,
                      description.field +
                          " is in the aircraft frame, but no T_p_w (the pylon "
                          "survey) was given to move it into the pylon frame");
    T_out_m = *T_p_w;
  }
  transform_mesh(body.mesh, description.scale_to_m, T_out_m);
  return body;
}

}  // namespace storetrack::clearance
