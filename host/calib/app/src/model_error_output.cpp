#include "model_error_output.hpp"

#include <nlohmann/json.hpp>

namespace storetrack::calibapp {
namespace {

nlohmann::json test_json(const calib::ModelErrorTest& t) {
  nlohmann::json flagged = nlohmann::json::array(), cells = nlohmann::json::array();
  for (const calib::ModelErrorCell& c : t.cells) {
    if (c.flagged) flagged.push_back({c.column, c.row});
    cells.push_back({{"column", c.column},
                     {"row", c.row},
                     {"centre_px", {c.centre_px.x(), c.centre_px.y()}},
                     {"points", c.points},
                     {"tested", c.tested},
                     {"value_px", {c.value_px.x(), c.value_px.y()}},
                     {"rms_px", c.rms_px},
                     {"sigma_px", c.sigma_px},
                     {"chi2", c.chi2},
                     {"flagged", c.flagged}});
  }
  nlohmann::json j = {{"available", t.available},         {"model_error", t.model_error},
                      {"tested_cells", t.tested_cells},   {"flagged_cells", t.flagged_cells},
                      {"allowed_cells", t.allowed_cells}, {"flagged", flagged}};
  if (t.joint_dof > 0) j["joint_p_value"] = t.joint_p_value;
  j["comment"] = {{"reason", t.reason},
                  {"cell_chi2_threshold", t.cell_threshold},
                  {"joint_chi2", t.joint_chi2},
                  {"joint_dof", t.joint_dof},
                  {"cells", cells}};
  return j;
}

}  // namespace

void print_model_error(const std::vector<calib::ModelErrorCheck>& checks, std::ostream& out) {
  for (const calib::ModelErrorCheck& c : checks)
    out << "model error check, camera " << c.camera_id << ": " << c.verdict << "\n";
}

std::string with_model_error(const std::string& calibration_json,
                             const std::vector<calib::ModelErrorCheck>& checks) {
  nlohmann::json doc = nlohmann::json::parse(calibration_json);
  for (nlohmann::json& cam : doc["cameras"])
    for (const calib::ModelErrorCheck& c : checks) {
      if (cam["camera_id"].get<int>() != c.camera_id) continue;
      cam["model_error"] = {{"verdict", c.verdict},
                            {"model_error_dominates", c.model_error},
                            {"cross_validation_distance_m", c.cross_validation_distance_m},
                            {"columns", c.residual_map.columns},
                            {"rows", c.residual_map.rows},
                            {"cross_validation", test_json(c.cross_validation)},
                            {"residual_map", test_json(c.residual_map)}};
    }
  return doc.dump(2) + "\n";
}

}  // namespace storetrack::calibapp
