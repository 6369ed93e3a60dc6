// Observation CSV reader and writer (docs/calibration.md, "Observation CSV"). Strict like the
// calibration file reader: a typo must never silently move a board point.
#include <array>
#include <charconv>
#include <cmath>
#include <fstream>
#include <sstream>
#include <string_view>

#include "storetrack/calib/observations.hpp"
#include "storetrack/csv/fields.hpp"
#include "storetrack/json/text_file.hpp"

namespace storetrack::calib {
namespace {

constexpr std::array<const char*, 9> kColumns = {"camera",     "frame",      "point_id",
                                                 "board_x_m",  "board_y_m",  "board_z_m",
                                                 "image_x_px", "image_y_px", "sigma_px"};
constexpr size_t kRequiredColumns = 8;

[[noreturn]] void fail(const std::string& origin, int line, const std::string& field,
                       const std::string& why) {
  throw ObservationFileError(origin + ":" + std::to_string(line) + ": " + field + ": " + why);
}

using csv::split_fields;
using csv::trim;

struct Cursor {
  const std::string& origin;
  int line;
  int integer(const std::string& text, const char* field, int lo, int hi) const {
    int v = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (ec != std::errc() || end != text.data() + text.size())
      fail(origin, line, field, "expected an integer, got '" + text + "'");
    if (v < lo || v > hi)
      fail(origin, line, field,
           std::to_string(v) + " out of range " + std::to_string(lo) + ".." + std::to_string(hi));
    return v;
  }
  double number(const std::string& text, const char* field) const {
    double v = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (ec != std::errc() || end != text.data() + text.size())
      fail(origin, line, field, "expected a number, got '" + text + "'");
    if (!std::isfinite(v)) fail(origin, line, field, "not finite");
    return v;
  }
};

/// "# image_size,<camera>,<width>,<height>" and "# frame,<frame>,<source>" comment lines.
void parse_metadata(const std::string& line, const Cursor& at, ObservationSet& set) {
  const auto cells = split_fields(trim(line.substr(1)), ',');
  if (cells.empty()) return;
  const std::string key = trim(cells[0]);
  if (key == "image_size") {
    if (cells.size() != 4) fail(at.origin, at.line, "image_size", "expected camera,width,height");
    const int cam = at.integer(trim(cells[1]), "image_size camera", 0, 255);
    set.image_sizes[cam] = {at.integer(trim(cells[2]), "image_size width", 1, 1 << 20),
                            at.integer(trim(cells[3]), "image_size height", 1, 1 << 20)};
  } else if (key == "frame" && cells.size() >= 3) {
    const int frame = at.integer(trim(cells[1]), "frame", 0, 1 << 30);
    std::string source = cells[2];
    for (size_t i = 3; i < cells.size(); ++i)
      source += "," + cells[i];
    set.frame_sources[frame] = trim(source);
  }
}

void check_header(const std::vector<std::string>& cells, const Cursor& at) {
  if (cells.size() != kRequiredColumns && cells.size() != kColumns.size())
    fail(at.origin, at.line, "header",
         "expected 8 or 9 columns (camera,frame,point_id,board_x_m,board_y_m,board_z_m,"
         "image_x_px,image_y_px[,sigma_px]), got " +
             std::to_string(cells.size()));
  for (size_t i = 0; i < cells.size(); ++i)
    if (trim(cells[i]) != kColumns[i])
      fail(at.origin, at.line, "header",
           "column " + std::to_string(i + 1) + " must be '" + kColumns[i] + "', got '" +
               trim(cells[i]) + "'");
}

Observation parse_row(const std::vector<std::string>& raw, size_t columns, const Cursor& at) {
  if (raw.size() != columns)
    fail(at.origin, at.line, "row",
         "expected " + std::to_string(columns) + " fields, got " + std::to_string(raw.size()));
  std::vector<std::string> c;
  for (const auto& cell : raw)
    c.push_back(trim(cell));
  Observation o;
  o.camera = at.integer(c[0], kColumns[0], 0, 255);
  o.frame = at.integer(c[1], kColumns[1], 0, 1 << 30);
  o.point_id = at.integer(c[2], kColumns[2], 0, 1 << 30);
  for (int i = 0; i < 3; ++i)
    o.p_board[i] = at.number(c[3 + i], kColumns[3 + i]);
  for (int i = 0; i < 2; ++i)
    o.pixel[i] = at.number(c[6 + i], kColumns[6 + i]);
  if (columns == kColumns.size() && !c[8].empty()) {
    const double s = at.number(c[8], kColumns[8]);
    if (!(s > 0)) fail(at.origin, at.line, kColumns[8], "must be > 0");
    o.sigma_px = s;
  }
  return o;
}

std::string format_point(const Eigen::Vector3d& p) {
  std::ostringstream s;
  s.precision(9);
  s << '(' << p.x() << ", " << p.y() << ", " << p.z() << ')';
  return s.str();
}

}  // namespace

std::string board_position_conflict(int point_id, const Eigen::Vector3d& here,
                                    const Eigen::Vector3d& before,
                                    const std::string& where_before) {
  const Eigen::Vector3d difference = here - before;
  if (difference.cwiseAbs().maxCoeff() <= kBoardPositionTolerance_m) return "";
  int column = 0;
  difference.cwiseAbs().maxCoeff(&column);
  std::ostringstream s;
  s << kColumns[3 + static_cast<size_t>(column)] << ": point " << point_id << " at "
    << format_point(here) << " m, but " << format_point(before) << " m " << where_before;
  if (before.norm() > 0 && here.norm() > 0) {
    s.precision(6);
    s << " (scale " << here.norm() / before.norm() << ": a different square size?)";
  }
  s << "; one board per calibration, every point at one board position";
  return s.str();
}

ObservationSet parse_observations_csv(const std::string& text, const std::string& origin) {
  ObservationSet set;
  std::istringstream in(text);
  std::string line;
  size_t columns = 0;
  std::map<std::array<int, 3>, int> seen;                // (camera, frame, point) -> line
  std::map<int, std::pair<Eigen::Vector3d, int>> board;  // point -> first position, its line
  for (int number = 1; std::getline(in, line); ++number) {
    const Cursor at{origin, number};
    const std::string t = trim(line);
    if (t.empty()) continue;
    if (t[0] == '#') {
      parse_metadata(t, at, set);
      continue;
    }
    if (columns == 0) {
      const auto cells = split_fields(t, ',');
      check_header(cells, at);
      columns = cells.size();
      continue;
    }
    Observation o = parse_row(split_fields(t, ','), columns, at);
    const auto [it, inserted] = seen.emplace(std::array{o.camera, o.frame, o.point_id}, number);
    if (!inserted)
      fail(origin, number, "point_id",
           "camera " + std::to_string(o.camera) + " frame " + std::to_string(o.frame) + " point " +
               std::to_string(o.point_id) + " already on line " + std::to_string(it->second));
    const auto [first, fresh] = board.emplace(o.point_id, std::pair(o.p_board, number));
    if (!fresh) {
      const std::string conflict =
          board_position_conflict(o.point_id, o.p_board, first->second.first,
                                  "on line " + std::to_string(first->second.second));
      if (!conflict.empty())
        throw ObservationFileError(origin + ":" + std::to_string(number) + ": " + conflict);
    }
    set.observations.push_back(o);
  }
  if (columns == 0) fail(origin, 1, "header", "no header line (empty file?)");
  return set;
}

ObservationSet read_observations_csv(const std::string& path) {
  std::string text;
  try {
    text = jsonfile::read_text_file(path);
  } catch (const jsonfile::FileReadError& e) {
    throw ObservationFileError(e.what());
  }
  return parse_observations_csv(text, path);
}

std::string format_observations_csv(const ObservationSet& set) {
  std::ostringstream out;
  out << "# storetrack board observations (docs/calibration.md)\n";
  for (const auto& [cam, size] : set.image_sizes)
    out << "# image_size," << cam << ',' << size.width << ',' << size.height << '\n';
  for (const auto& [frame, source] : set.frame_sources)
    out << "# frame," << frame << ',' << source << '\n';
  for (size_t i = 0; i < kColumns.size(); ++i)
    out << (i ? "," : "") << kColumns[i];
  out << '\n';
  char buf[64];
  const auto put = [&](double v) {  // shortest text that reads back bit for bit
    const auto end = std::to_chars(buf, buf + sizeof buf, v).ptr;
    out << ',' << std::string_view(buf, static_cast<size_t>(end - buf));
  };
  for (const Observation& o : set.observations) {
    out << o.camera << ',' << o.frame << ',' << o.point_id;
    for (int i = 0; i < 3; ++i)
      put(o.p_board[i]);
    for (int i = 0; i < 2; ++i)
      put(o.pixel[i]);
    if (o.sigma_px)
      put(*o.sigma_px);
    else
      out << ',';
    out << '\n';
  }
  return out.str();
}

void write_observations_csv(const ObservationSet& set, const std::string& path) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw ObservationFileError(path + ": cannot open for writing");
  out << format_observations_csv(set);
  if (!out.flush()) throw ObservationFileError(path + ": write failed");
}

}  // namespace storetrack::calib
