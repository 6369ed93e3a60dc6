// ChArUco detection: OpenCV's markers (detectMarkers, then refineDetectedMarkers to recover
// markers the first pass missed, with the board's layout), then interpolateCornersCharuco (local
// homographies of the adjacent markers, cornerSubPix). Every image or corner not used gets a
// reason; an image without the board's markers is checked against the other dictionaries, so a
// wrong --dictionary is named as such.
#include <opencv2/aruco/charuco.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <set>
#include <utility>

#include "image_set_check.hpp"
#include "storetrack/calib/charuco_detection.hpp"

namespace storetrack::calib {
namespace {

using cv::aruco::PREDEFINED_DICTIONARY_NAME;

const std::vector<std::pair<std::string, PREDEFINED_DICTIONARY_NAME>>& dictionaries() {
  static const std::vector<std::pair<std::string, PREDEFINED_DICTIONARY_NAME>> all = {
      {"DICT_4X4_50", cv::aruco::DICT_4X4_50},
      {"DICT_4X4_100", cv::aruco::DICT_4X4_100},
      {"DICT_4X4_250", cv::aruco::DICT_4X4_250},
      {"DICT_4X4_1000", cv::aruco::DICT_4X4_1000},
      {"DICT_5X5_50", cv::aruco::DICT_5X5_50},
      {"DICT_5X5_100", cv::aruco::DICT_5X5_100},
      {"DICT_5X5_250", cv::aruco::DICT_5X5_250},
      {"DICT_5X5_1000", cv::aruco::DICT_5X5_1000},
      {"DICT_6X6_50", cv::aruco::DICT_6X6_50},
      {"DICT_6X6_100", cv::aruco::DICT_6X6_100},
      {"DICT_6X6_250", cv::aruco::DICT_6X6_250},
      {"DICT_6X6_1000", cv::aruco::DICT_6X6_1000},
      {"DICT_7X7_50", cv::aruco::DICT_7X7_50},
      {"DICT_7X7_100", cv::aruco::DICT_7X7_100},
      {"DICT_7X7_250", cv::aruco::DICT_7X7_250},
      {"DICT_7X7_1000", cv::aruco::DICT_7X7_1000},
      {"DICT_ARUCO_ORIGINAL", cv::aruco::DICT_ARUCO_ORIGINAL},
      {"DICT_APRILTAG_16h5", cv::aruco::DICT_APRILTAG_16h5},
      {"DICT_APRILTAG_25h9", cv::aruco::DICT_APRILTAG_25h9},
      {"DICT_APRILTAG_36h10", cv::aruco::DICT_APRILTAG_36h10},
      {"DICT_APRILTAG_36h11", cv::aruco::DICT_APRILTAG_36h11}};
  return all;
}

cv::Ptr<cv::aruco::CharucoBoard> make_board(const CharucoSpec& spec) {
  const auto& all = dictionaries();
  const auto it = std::find_if(all.begin(), all.end(),
                               [&](const auto& d) { return d.first == spec.dictionary; });
  if (it == all.end())
    throw CharucoSpecError("--dictionary: unknown dictionary '" + spec.dictionary +
                           "' (OpenCV's names, e.g. DICT_5X5_100)");
  if (spec.squares_x < 2 || spec.squares_y < 2)
    throw CharucoSpecError("--squares-x, --squares-y: a ChArUco board needs >= 2 x 2 squares");
  if (!(spec.marker_m > 0 && spec.marker_m < spec.square_m))
    throw CharucoSpecError("--marker: the marker side must be > 0 and smaller than --square");
  const cv::Ptr<cv::aruco::Dictionary> dictionary = cv::aruco::getPredefinedDictionary(it->second);
  const int markers = spec.squares_x * spec.squares_y / 2;
  if (markers > dictionary->bytesList.rows)
    throw CharucoSpecError("--dictionary: " + spec.dictionary + " has " +
                           std::to_string(dictionary->bytesList.rows) + " markers, a " +
                           std::to_string(spec.squares_x) + "x" + std::to_string(spec.squares_y) +
                           " board needs " + std::to_string(markers));
  return cv::aruco::CharucoBoard::create(spec.squares_x, spec.squares_y,
                                         static_cast<float>(spec.square_m),
                                         static_cast<float>(spec.marker_m), dictionary);
}

cv::Ptr<cv::aruco::DetectorParameters> detector_parameters() {
  cv::Ptr<cv::aruco::DetectorParameters> p = cv::aruco::DetectorParameters::create();
  // The markers only locate and identify the corners; the corners are refined themselves.
  p->cornerRefinementMethod = cv::aruco::CORNER_REFINE_NONE;
  return p;
}

struct Markers {
  std::vector<std::vector<cv::Point2f>> corners, rejected;
  std::vector<int> ids;
};

Markers detect_markers(const cv::Mat& gray, const cv::Ptr<cv::aruco::Dictionary>& dictionary) {
  Markers m;
  cv::aruco::detectMarkers(gray, dictionary, m.corners, m.ids, detector_parameters(), m.rejected);
  return m;
}

/// Why an image shows no marker of the board: the dictionary that does find markers, if any.
std::string no_marker_reason(const cv::Mat& gray, const CharucoSpec& spec) {
  std::string best_name;
  size_t best = 0;
  for (const auto& [name, id] : dictionaries()) {
    if (name == spec.dictionary) continue;
    const size_t n = detect_markers(gray, cv::aruco::getPredefinedDictionary(id)).ids.size();
    if (n > best) best = n, best_name = name;
  }
  std::string reason = "no marker of " + spec.dictionary + " found";
  if (best >= 2)
    reason +=
        "; " + std::to_string(best) + " markers of " + best_name + " are: wrong --dictionary?";
  return reason + " (board not in the image, too small, blurred or over-exposed)";
}

/// Keeps the markers of the board (ids 0 .. markers-1); returns the count of the others.
int drop_foreign_markers(Markers& m, int board_markers) {
  Markers kept;
  for (size_t i = 0; i < m.ids.size(); ++i)
    if (m.ids[i] < board_markers) {
      kept.ids.push_back(m.ids[i]);
      kept.corners.push_back(m.corners[i]);
    }
  const int foreign = static_cast<int>(m.ids.size() - kept.ids.size());
  kept.rejected = std::move(m.rejected);
  m = std::move(kept);
  return foreign;
}

void reject_partly_seen_corners(const cv::aruco::CharucoBoard& board, const Markers& m,
                                const std::vector<int>& corner_ids, int frame,
                                std::vector<RejectedCorner>& out) {
  const std::set<int> seen_markers(m.ids.begin(), m.ids.end());
  const std::set<int> found(corner_ids.begin(), corner_ids.end());
  for (int id = 0; id < static_cast<int>(board.nearestMarkerIdx.size()); ++id) {
    if (found.count(id)) continue;
    int adjacent = 0, seen = 0;
    for (int marker_index : board.nearestMarkerIdx[static_cast<size_t>(id)]) {
      ++adjacent;
      seen += static_cast<int>(seen_markers.count(board.ids[static_cast<size_t>(marker_index)]));
    }
    if (seen == 0) continue;  // not in view: nothing was rejected
    const std::string reason =
        seen < 2 ? std::to_string(seen) + " of its " + std::to_string(adjacent) +
                       " adjacent markers detected (need 2 to locate it)"
                 : "its adjacent markers were detected but OpenCV did not return it "
                   "(interpolated outside the image or its sub-pixel refinement failed)";
    out.push_back({frame, id, reason});
  }
}

}  // namespace

std::vector<std::string> charuco_dictionary_names() {
  std::vector<std::string> names;
  for (const auto& d : dictionaries())
    names.push_back(d.first);
  return names;
}

Eigen::Vector3d charuco_corner_position(const CharucoSpec& board, int id) {
  const int cols = board.squares_x - 1;
  return {(id % cols + 1) * board.square_m, (id / cols + 1) * board.square_m, 0.0};
}

namespace {

/// The pixel-centre origin of interpolateCornersCharuco's corners in OpenCV 4.6: (0.5, 0.5)
/// (opencv_contrib PR 3024 adds 0.5 to cornerSubPix's result; opencv issue 25539), where
/// conventions.md, cornerSubPix and findChessboardCorners put it at (0, 0).
constexpr float kCharucoPixelOrigin = 0.5f;

/// Refines the corners again, to convergence: OpenCV 4.6 refines them with its default
/// detector parameters, which stop once a step is below 0.1 px (rendered truth: RMS error
/// 0.10 px, max 0.32 px noise-free). The window is OpenCV's choice: up to 2 px short of the
/// nearest detected corner of an adjacent marker (so no marker edge enters it), 2..10 px.
void refine_corners(const cv::Mat& gray, const cv::aruco::CharucoBoard& board,
                    const std::vector<std::vector<cv::Point2f>>& marker_corners,
                    const std::vector<int>& marker_ids, std::vector<cv::Point2f>& corners,
                    const std::vector<int>& ids) {
  for (size_t i = 0; i < corners.size(); ++i) {
    cv::Point2f& c = corners[i];
    c -= cv::Point2f(kCharucoPixelOrigin, kCharucoPixelOrigin);
    double nearest = 1e9;
    const auto id = static_cast<size_t>(ids[i]);
    for (size_t k = 0; k < board.nearestMarkerIdx[id].size(); ++k) {
      const int marker = board.ids[static_cast<size_t>(board.nearestMarkerIdx[id][k])];
      const auto at = std::find(marker_ids.begin(), marker_ids.end(), marker);
      if (at == marker_ids.end()) continue;
      const cv::Point2f& q = marker_corners[static_cast<size_t>(at - marker_ids.begin())]
                                           [static_cast<size_t>(board.nearestMarkerCorners[id][k])];
      nearest = std::min(nearest, static_cast<double>(std::hypot(q.x - c.x, q.y - c.y)));
    }
    const int half = std::clamp(static_cast<int>(nearest / std::sqrt(2.0)) - 1, 2, 10);
    std::vector<cv::Point2f> one{c};
    cv::cornerSubPix(gray, one, cv::Size(half, half), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-4));
    c = one[0];
  }
}

struct ViewCorners {
  std::vector<cv::Point2f> corners;
  std::vector<int> ids;
  std::string reason;  ///< non-empty: the view is rejected
};

ViewCorners detect_view(const cv::Mat& gray, const cv::Ptr<cv::aruco::CharucoBoard>& board,
                        const CharucoSpec& spec, int frame, std::vector<RejectedCorner>& partly) {
  ViewCorners v;
  Markers m = detect_markers(gray, board->dictionary);
  if (m.ids.empty()) {
    v.reason = no_marker_reason(gray, spec);
    return v;
  }
  const int board_markers = static_cast<int>(board->ids.size());
  const int found = static_cast<int>(m.ids.size());
  const int foreign = drop_foreign_markers(m, board_markers);
  if (m.ids.empty()) {
    v.reason = std::to_string(found) + " markers of " + spec.dictionary +
               " found, none with an id of this board (0.." + std::to_string(board_markers - 1) +
               "): wrong --squares-x/--squares-y or another board";
    return v;
  }
  cv::aruco::refineDetectedMarkers(gray, board, m.corners, m.ids, m.rejected, cv::noArray(),
                                   cv::noArray(), 10.f, 3.f, true, cv::noArray(),
                                   detector_parameters());
  cv::aruco::interpolateCornersCharuco(m.corners, m.ids, gray, board, v.corners, v.ids);
  refine_corners(gray, *board, m.corners, m.ids, v.corners, v.ids);
  const std::string markers_text =
      std::to_string(m.ids.size()) + " board markers" +
      (foreign ? " (and " + std::to_string(foreign) + " markers not on this board, ignored)"
               : std::string());
  if (static_cast<int>(v.ids.size()) < spec.min_corners) {
    v.reason = "too few corners: " + std::to_string(v.ids.size()) + " from " + markers_text +
               ", need >= " + std::to_string(spec.min_corners) + " (--min-corners)";
    return v;
  }
  if (cv::aruco::testCharucoCornersCollinear(board, v.ids)) {
    v.reason = "the " + std::to_string(v.ids.size()) +
               " corners lie on one line of the board: no homography";
    return v;
  }
  reject_partly_seen_corners(*board, m, v.ids, frame, partly);
  return v;
}

}  // namespace

CharucoDetectionResult detect_charuco(const std::vector<std::string>& image_paths,
                                      const CharucoSpec& spec, int camera) {
  const cv::Ptr<cv::aruco::CharucoBoard> board = make_board(spec);
  CharucoDetectionResult out;
  DetectionResult& d = out.detection;
  ImageSetCheck images;
  for (size_t frame = 0; frame < image_paths.size(); ++frame) {
    const std::string& path = image_paths[frame];
    const cv::Mat gray = cv::imread(path, cv::IMREAD_GRAYSCALE);
    if (std::string reason = images.reason(gray); !reason.empty()) {
      d.rejected.push_back({path, std::move(reason)});
      continue;
    }
    const ViewCorners v =
        detect_view(gray, board, spec, static_cast<int>(frame), out.rejected_corners);
    if (!v.reason.empty()) {
      d.rejected.push_back({path, v.reason});
      continue;
    }
    for (size_t i = 0; i < v.ids.size(); ++i) {
      Observation o;
      o.camera = camera;
      o.frame = static_cast<int>(frame);
      o.point_id = v.ids[i];
      o.p_board = charuco_corner_position(spec, v.ids[i]);
      o.pixel = {v.corners[i].x, v.corners[i].y};
      d.set.observations.push_back(o);
    }
    d.set.frame_sources[static_cast<int>(frame)] = path;
    ++d.images_used;
  }
  if (!images.size().empty())
    d.set.image_sizes[camera] = {images.size().width, images.size().height};
  return out;
}

}  // namespace storetrack::calib
