#include "detect_report.hpp"

#include <map>

#include "command_output.hpp"

namespace storetrack::calibapp {

void add_charuco_options(cli::Command& sub, calib::CharucoSpec& spec) {
  sub.option("--squares-x", spec.squares_x, "ChArUco: squares per board row").range(2, 1000);
  sub.option("--squares-y", spec.squares_y, "ChArUco: squares per board column").range(2, 1000);
  sub.option("--marker", spec.marker_m, "ChArUco: marker side [m] (< --square)").positive();
  sub.option("--dictionary", spec.dictionary, "ChArUco: OpenCV dictionary, e.g. DICT_5X5_100");
  sub.option("--min-corners", spec.min_corners, "ChArUco: fewest corners for a view to be used")
      .range(4, 1000000);
}

nlohmann::json detect_report_json(const DetectArgs& args, const calib::DetectionResult& result,
                                  const std::vector<calib::RejectedCorner>& rejected_corners) {
  std::map<std::string, std::string> reason_of;
  for (const auto& r : result.rejected)
    reason_of.emplace(r.path, r.reason);
  std::map<int, int> points_of;
  for (const auto& o : result.set.observations)
    ++points_of[o.frame];
  nlohmann::json images = nlohmann::json::array();
  for (size_t frame = 0; frame < args.images.size(); ++frame) {
    const std::string& path = args.images[frame];
    const auto reason = reason_of.find(path);
    const bool used = result.set.frame_sources.count(static_cast<int>(frame)) != 0;
    images.push_back({{"frame", frame},
                      {"path", path},
                      {"used", used},
                      {"points", used ? points_of[static_cast<int>(frame)] : 0},
                      {"reason", used || reason == reason_of.end() ? "" : reason->second}});
  }
  nlohmann::json corners = nlohmann::json::array();
  for (const auto& c : rejected_corners)
    corners.push_back({{"frame", c.frame}, {"point_id", c.point_id}, {"reason", c.reason}});
  nlohmann::json points = nlohmann::json::array();  // [frame, point_id, x_px, y_px]
  for (const auto& o : result.set.observations)
    points.push_back({o.frame, o.point_id, o.pixel.x(), o.pixel.y()});
  nlohmann::json board = {{"type", args.board}, {"square_m", args.chessboard.square_m}};
  if (args.board == "charuco") {
    board["squares_x"] = args.charuco.squares_x;
    board["squares_y"] = args.charuco.squares_y;
    board["marker_m"] = args.charuco.marker_m;
    board["dictionary"] = args.charuco.dictionary;
    board["min_corners"] = args.charuco.min_corners;
  } else {
    board["cols"] = args.chessboard.cols;
    board["rows"] = args.chessboard.rows;
  }
  nlohmann::json size = nullptr;
  if (const auto it = result.set.image_sizes.find(args.camera); it != result.set.image_sizes.end())
    size = {it->second.width, it->second.height};
  return {{"format", "storetrack-calib-detect"},
          {"camera", args.camera},
          {"board", board},
          {"observations_csv", args.output},
          {"image_size", size},
          {"images_used", result.images_used},
          {"images", images},
          {"rejected_corners", corners},
          {"points", points}};
}

void write_detect_report(const DetectArgs& args, const calib::DetectionResult& result,
                         const std::vector<calib::RejectedCorner>& rejected_corners) {
  if (args.report_json.empty()) return;
  write_text(args.report_json, detect_report_json(args, result, rejected_corners).dump(1) + "\n");
}

int run_detect_charuco(const DetectArgs& args, std::ostream& out, std::ostream& err) {
  calib::CharucoSpec spec = args.charuco;
  spec.square_m = args.chessboard.square_m;
  calib::CharucoDetectionResult result;
  try {
    result = calib::detect_charuco(args.images, spec, args.camera);
  } catch (const calib::CharucoSpecError& e) {
    err << "error: " << e.what() << "\n";
    return 2;
  }
  const calib::DetectionResult& d = result.detection;
  for (const auto& rejected : d.rejected)
    err << "rejected " << rejected.path << ": " << rejected.reason << "\n";
  for (const auto& c : result.rejected_corners)
    err << "rejected corner " << c.point_id << " of " << args.images[static_cast<size_t>(c.frame)]
        << ": " << c.reason << "\n";
  out << "detect: " << d.images_used << " of " << args.images.size() << " images used, "
      << d.rejected.size() << " rejected, " << d.set.observations.size() << " corners, "
      << result.rejected_corners.size() << " corners rejected (ChArUco " << spec.squares_x << "x"
      << spec.squares_y << " squares of " << spec.square_m << " m, markers " << spec.marker_m
      << " m, " << spec.dictionary << ")\n";
  // The report first: with no image used it still says why each gave nothing.
  if (!wrote_or_reported(err, [&] { write_detect_report(args, d, result.rejected_corners); }))
    return 1;
  if (d.images_used == 0) {
    err << "error: no image gave a ChArUco board; nothing written\n";
    return 2;
  }
  return write_outputs(args.output, out, err,
                       [&] { calib::write_observations_csv(d.set, args.output); });
}

}  // namespace storetrack::calibapp
