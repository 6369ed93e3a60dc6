// The host's marks CSV, read strictly: a missing column or a non-finite position must stop the
// evaluation with the file, line and field, never shift a mark silently.
#include <algorithm>
#include <array>
#include <charconv>
#include <climits>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <map>
#include <sstream>
#include <string_view>
#include <utility>

#include "storetrack/eval/marks_csv.hpp"

#include "storetrack/csv/fields.hpp"
#include "storetrack/json/text_file.hpp"

namespace storetrack::eval {
namespace {

// The columns the evaluation needs, by the name before the unit ("x_w [m]" -> "x_w").
// The optional off-diagonal covariance columns follow kColumnCount (older files lack them).
enum Column {
  kSeq,
  kMarkId,
  kBody,
  kExcluded,
  kX,
  kY,
  kZ,
  kUx,
  kUy,
  kUz,
  kColumnCount,
  kCovXy = kColumnCount,
  kCovXz,
  kCovYz,
  kAllColumns
};
constexpr std::array<const char*, kAllColumns> kNames = {
    "trigger_seq", "mark_id", "body",  "excluded", "x_w",      "y_w",     "z_w",
    "u_x_w",       "u_y_w",   "u_z_w", "cov_xy_w", "cov_xz_w", "cov_yz_w"};
// Optional columns: the exposure time and the per-camera observation (noise floor's image
// coordinates and stereo angles).
enum OptionalColumn { kTime, kCamera, kUObs, kVObs, kResU, kResV, kSigma, kOptionalCount };
constexpr std::array<const char*, kOptionalCount> kOptionalNames = {
    "reference_mid_tai_ns", "camera_id", "u_obs", "v_obs", "residual_u", "residual_v", "sigma"};

[[noreturn]] void fail(const std::string& origin, int line, const std::string& field,
                       const std::string& why) {
  throw EvalInputError(origin + ":" + std::to_string(line) + ": " + field + ": " + why);
}

std::string column_name(std::string cell) {
  const auto bracket = cell.find('[');
  if (bracket != std::string::npos) cell.resize(bracket);
  return csv::trim(cell);
}

std::array<int, kAllColumns> header_columns(const std::string& header, const std::string& origin,
                                            std::array<int, kOptionalCount>& optional) {
  std::array<int, kAllColumns> index;
  index.fill(-1);
  optional.fill(-1);
  const std::vector<std::string> cells = csv::split_fields(header);
  for (size_t i = 0; i < cells.size(); ++i) {
    const std::string name = column_name(cells[i]);
    for (int c = 0; c < kAllColumns; ++c)
      if (name == kNames[static_cast<size_t>(c)])
        index[static_cast<size_t>(c)] = static_cast<int>(i);
    for (int c = 0; c < kOptionalCount; ++c)
      if (name == kOptionalNames[static_cast<size_t>(c)])
        optional[static_cast<size_t>(c)] = static_cast<int>(i);
  }
  for (int c = 0; c < kColumnCount; ++c)
    if (index[static_cast<size_t>(c)] < 0)
      fail(origin, 1, kNames[static_cast<size_t>(c)], "missing column in the header");
  const int covariance_columns = (index[kCovXy] >= 0) + (index[kCovXz] >= 0) + (index[kCovYz] >= 0);
  if (covariance_columns != 0 && covariance_columns != 3)
    for (int c = kCovXy; c < kAllColumns; ++c)
      if (index[static_cast<size_t>(c)] < 0)
        fail(origin, 1, kNames[static_cast<size_t>(c)],
             "missing column in the header (the covariance columns come as a set of three)");
  return index;
}

long long parse_integer(const std::string& text, const std::string& origin, int line,
                        const char* name, long long lo, long long hi) {
  long long v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size())
    fail(origin, line, name, "expected an integer, got '" + text + "'");
  if (v < lo || v > hi) fail(origin, line, name, "'" + text + "' out of range");
  return v;
}

// `allow_nan`: the host writes "nan" for a centroid it could not look up (kept, counted later).
double parse_number(const std::string& text, const std::string& origin, int line, const char* name,
                    bool allow_nan = false) {
  double v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size())
    fail(origin, line, name, "expected a number, got '" + text + "'");
  if (!std::isfinite(v) && !(allow_nan && std::isnan(v)))
    fail(origin, line, name, "not finite ('" + text + "')");
  return v;
}

struct Row {
  const std::vector<std::string>& cells;
  const std::array<int, kAllColumns>& index;
  const std::string& origin;
  int line;
  const std::array<int, kOptionalCount>* optional = nullptr;

  const std::string& cell(Column c) const { return cells[static_cast<size_t>(index[c])]; }
  long long integer(Column c, long long lo, long long hi) const {
    return parse_integer(cell(c), origin, line, kNames[c], lo, hi);
  }
  double number(Column c) const { return parse_number(cell(c), origin, line, kNames[c]); }
  const std::string& cell(OptionalColumn c) const {
    return cells[static_cast<size_t>((*optional)[c])];
  }
  double number(OptionalColumn c, bool allow_nan = false) const {
    return parse_number(cell(c), origin, line, kOptionalNames[c], allow_nan);
  }
};

/// The observation columns of a row (all present: checked by the caller).
MarkObservationSample observation_of(const Row& row) {
  MarkObservationSample o;
  o.camera_id = static_cast<int>(
      parse_integer(row.cell(kCamera), row.origin, row.line, kOptionalNames[kCamera], 0, 255));
  o.pixel_px = {row.number(kUObs, true), row.number(kVObs, true)};
  o.residual_px = {row.number(kResU, true), row.number(kResV, true)};
  o.sigma_px = row.number(kSigma);
  if (!(o.sigma_px > 0)) fail(row.origin, row.line, "sigma", "centroid sigma not > 0");
  return o;
}

}  // namespace

MarksRecording parse_marks_csv(const std::string& text, const std::string& origin) {
  MarksRecording rec;
  rec.path = origin;
  std::istringstream in(text);
  std::string line_text;
  if (!std::getline(in, line_text)) fail(origin, 1, "header", "empty file");
  std::array<int, kOptionalCount> optional;
  const std::array<int, kAllColumns> index = header_columns(line_text, origin, optional);
  const bool full_covariance = index[kCovXy] >= 0;
  int needed = 0;
  for (int i : index)
    needed = std::max(needed, i + 1);
  rec.has_time = optional[kTime] >= 0;
  if (rec.has_time) needed = std::max(needed, optional[kTime] + 1);
  for (int c = kCamera; c < kOptionalCount; ++c)
    if (optional[static_cast<size_t>(c)] < 0)
      rec.missing_observation_columns.push_back(kOptionalNames[static_cast<size_t>(c)]);
  rec.has_observations = rec.missing_observation_columns.empty();
  if (rec.has_observations)
    for (int c = kCamera; c < kOptionalCount; ++c)
      needed = std::max(needed, optional[static_cast<size_t>(c)] + 1);
  std::map<std::pair<std::uint32_t, int>, size_t> seen;  // one sample per (exposure, mark)
  for (int line = 2; std::getline(in, line_text); ++line) {
    if (column_name(line_text).empty()) continue;
    const std::vector<std::string> cells = csv::split_fields(line_text);
    if (static_cast<int>(cells.size()) < needed)
      fail(origin, line, "row",
           std::to_string(cells.size()) + " cells, the header needs " + std::to_string(needed));
    const Row row{cells, index, origin, line, &optional};
    if (row.integer(kExcluded, 0, 1) == 1) {
      ++rec.excluded_rows;
      continue;
    }
    MarkSample s;
    s.trigger_seq = static_cast<std::uint32_t>(row.integer(kSeq, 0, 0xFFFFFFFFLL));
    s.mark_id = static_cast<int>(row.integer(kMarkId, 0, 1000000));
    const std::string& body = row.cell(kBody);
    if (body.size() != 1) fail(origin, line, "body", "expected p, s or ?, got '" + body + "'");
    s.body = body[0];
    s.p_w = {row.number(kX), row.number(kY), row.number(kZ)};
    s.u_w = {row.number(kUx), row.number(kUy), row.number(kUz)};
    for (int a = 0; a < 3; ++a)
      if (!(s.u_w(a) > 0)) fail(origin, line, kNames[kUx + a], "standard uncertainty not > 0");
    s.cov_w = s.u_w.cwiseAbs2().asDiagonal();
    if (full_covariance) {
      s.full_covariance = true;
      s.cov_w(0, 1) = s.cov_w(1, 0) = row.number(kCovXy);
      s.cov_w(0, 2) = s.cov_w(2, 0) = row.number(kCovXz);
      s.cov_w(1, 2) = s.cov_w(2, 1) = row.number(kCovYz);
    }
    s.line = line;
    if (rec.has_time)
      s.reference_mid_tai_ns = static_cast<std::int64_t>(
          parse_integer(row.cell(kTime), origin, line, kOptionalNames[kTime], 0, INT64_MAX));
    if (rec.has_observations) s.observations.push_back(observation_of(row));
    const auto key = std::make_pair(s.trigger_seq, s.mark_id);
    if (const auto it = seen.find(key); it != seen.end()) {
      // The same triangulated mark, repeated for each camera that saw it.
      if ((rec.samples[it->second].p_w - s.p_w).norm() > 1e-6)
        fail(origin, line, "x_w",
             "mark " + std::to_string(s.mark_id) + " of trigger_seq " +
                 std::to_string(s.trigger_seq) + " differs from its row on line " +
                 std::to_string(rec.samples[it->second].line));
      ++rec.samples[it->second].camera_rows;
      if (rec.has_observations) rec.samples[it->second].observations.push_back(s.observations[0]);
      continue;
    }
    seen.emplace(key, rec.samples.size());
    rec.samples.push_back(s);
  }
  if (rec.samples.empty()) fail(origin, 2, "rows", "no mark samples (excluded rows left out)");
  return rec;
}

MarksRecording read_marks_csv(const std::string& path) {
  std::string text;
  try {
    text = jsonfile::read_text_file(path);
  } catch (const jsonfile::FileReadError& e) {
    throw EvalInputError(std::string(e.what()) + " (marks CSV)");
  }
  return parse_marks_csv(text, path);
}

}  // namespace storetrack::eval
