// storetrack-sim: runs a scenario of the scene simulator and writes it to disk.
//
//   storetrack-sim --scenario store_separation --cameras 4 --seed 1 --out /tmp/sep
//                  [--mode frames|observations|boards] [--exposures N]
//   storetrack-sim --scenario static --mode boards --out /tmp/boards [--board-cols 10 ...]
//
// Output files are described in common/sim/README.md. Exit codes: 0 ok, 1 I/O or runtime
// error, 2 bad arguments or bad scenario file.
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

#include "storetrack/cli/command_line.hpp"

#include "board_images.hpp"
#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/msg/udp_codec.hpp"
#include "storetrack/sim/frame_source.hpp"
#include "storetrack/sim/pendulum_truth.hpp"
#include "storetrack/sim/scenario.hpp"
#include "storetrack/sim/simulator.hpp"

namespace {

using namespace storetrack;

std::string resolve_scenario(const std::string& arg) {
  if (arg.find('/') == std::string::npos && arg.find(".json") == std::string::npos) {
    return std::string(STORETRACK_SIM_SCENARIO_DIR) + "/" + arg + ".json";
  }
  return arg;
}

void write_observations(const sim::Simulator& sim, const std::string& dir) {
  std::ofstream csv(dir + "/observations.csv");
  std::ofstream udp(dir + "/observations.udp", std::ios::binary);
  if (!csv || !udp) throw std::runtime_error(dir + ": cannot write observation files");
  csv << "trigger_seq,unit_id,camera_id,exposure_start_tai_ns,exposure_start_mono_ns,"
         "exposure_duration_ns,clock_state,exposure_flags,mark_index,x_px,y_px,sigma_px,"
         "peak_dn,diameter_px,mark_flags,true_mark_id\n";
  csv.precision(10);
  msg::MarkObservations obs;
  std::vector<int> ids;
  std::vector<std::uint8_t> buf(msg::kMaxDatagramBytes);
  std::uint32_t datagram_seq = 0;
  for (int k = 0; k < sim.num_exposures(); ++k) {
    for (int c = 0; c < sim.num_cameras(); ++c) {
      sim.observe(k, c, obs, &ids);
      for (int i = 0; i < obs.mark_count; ++i) {
        const msg::MarkObservation& m = obs.marks[static_cast<std::size_t>(i)];
        csv << obs.trigger_seq << "," << int{obs.unit_id} << "," << int{obs.camera_id} << ","
            << obs.exposure_start_tai_ns << "," << obs.exposure_start_mono_ns << ","
            << obs.exposure_duration_ns << "," << int{obs.clock_state} << "," << obs.flags << ","
            << i << "," << m.x_px << "," << m.y_px << "," << m.sigma_px << "," << m.peak << ","
            << m.diameter_px << "," << int{m.flags} << "," << ids[static_cast<std::size_t>(i)]
            << "\n";
      }
      const int n = msg::encode_datagram(obs, buf, datagram_seq++);
      if (n < 0) throw std::runtime_error("encode_datagram failed: " + std::to_string(n));
      // Length-prefixed (u32 big-endian) UDP datagrams, in send order.
      const std::uint32_t len = static_cast<std::uint32_t>(n);
      const char prefix[4] = {static_cast<char>(len >> 24), static_cast<char>(len >> 16),
                              static_cast<char>(len >> 8), static_cast<char>(len)};
      udp.write(prefix, 4);
      udp.write(reinterpret_cast<const char*>(buf.data()), n);
    }
  }
  if (!csv || !udp) throw std::runtime_error(dir + ": observation write failed");
}

// The world registration's inputs (storetrack-calib register, docs/calibration.md): the
// total-station survey of the registration marks in S_w and their hangar observations in the
// observation CSV of storetrack-calib (point_id = mark id, board coordinates 0, sigma_px the
// centroid's). Border-cut and merged blobs are left out, as a unit's operator would.
void write_registration(const sim::Simulator& sim, const std::string& dir) {
  survey::write_survey(sim.registration_survey(false), dir + "/survey_aircraft.json");
  survey::write_survey(sim.registration_survey(true), dir + "/true_survey_aircraft.json");
  std::ofstream csv(dir + "/registration_marks.csv");
  if (!csv) throw std::runtime_error(dir + ": cannot write registration_marks.csv");
  csv << "# storetrack board observations (docs/calibration.md): registration marks, "
         "storetrack-sim hangar exposure\n";
  for (const camera::CalibratedCamera& c : sim.true_rig().cameras) {
    csv << "# image_size," << c.camera_id << "," << c.model.intrinsics().width << ","
        << c.model.intrinsics().height << "\n";
  }
  csv << "camera,frame,point_id,board_x_m,board_y_m,board_z_m,image_x_px,image_y_px,sigma_px\n";
  csv.precision(9);  // float32 wire values: 9 significant digits read back exactly
  for (const auto& r : sim.registration_sightings())
    csv << r.camera_id << ",0," << r.mark_id << ",0,0,0," << r.px.x() << "," << r.px.y() << ","
        << r.sigma_px << "\n";
  if (!csv) throw std::runtime_error(dir + ": registration_marks.csv write failed");
}

}  // namespace

int main(int argc, char** argv) {
  storetrack::cli::Command app{
      "storetrack-sim: scene simulator (frames, observations, truth, rig calibration)"};
  std::string scenario_arg = "store_separation";
  int cameras = 0;
  std::uint64_t seed = 1;
  std::string out_dir;
  std::string mode = "observations";
  int exposures = 0;
  app.option("--scenario", scenario_arg,
             "Scenario JSON file, or a built-in name (store_separation, pendulum, static, "
             "scale_bars)")
      .show_default();
  app.option("--cameras", cameras, "Use the first N cameras of the scenario (2..4; 0: all)")
      .range(0, 8);
  app.option("--seed", seed, "Random seed (noise, calibration and survey errors)").show_default();
  app.option("--out", out_dir, "Output directory (created)").required();
  app.option("--mode", mode,
             "frames: PGM images + triggers.csv; observations: fast mode; boards: calibration "
             "board images of the rig + rig_true.json + boards/truth.json only")
      .one_of({"frames", "observations", "boards"})
      .show_default();
  sim::BoardSetOptions boards;
  app.option("--board-cols", boards.board.cols, "boards: inner corners per row")
      .range(3, 40)
      .show_default();
  app.option("--board-rows", boards.board.rows, "boards: inner corners per column")
      .range(3, 40)
      .show_default();
  app.option("--board-square", boards.board.square_m, "boards: square size [m]")
      .range(0.001, 1.0)
      .show_default();
  app.option("--board-common-views", boards.common_views,
             "boards: frames camera 0 and each other camera see together")
      .range(0, 100)
      .show_default();
  app.option("--board-single-views", boards.single_views,
             "boards: frames per camera over a 3x3 grid of its image")
      .range(0, 100)
      .show_default();
  app.option("--exposures", exposures, "Limit the number of exposures (0: scenario's)")
      .range(0, 1000000);
  if (const int rc = app.parse(argc, argv); rc >= 0) return rc;

  sim::Scenario scenario;
  try {
    scenario = sim::load_scenario(resolve_scenario(scenario_arg));
  } catch (const std::exception& e) {
    std::cerr << "storetrack-sim: " << e.what() << "\n";
    return 2;
  }
  if (cameras != 0) {
    if (cameras < 2 || cameras > static_cast<int>(scenario.cameras.size())) {
      std::cerr << "storetrack-sim: --cameras " << cameras << ": the scenario has "
                << scenario.cameras.size() << " cameras (use 2.." << scenario.cameras.size()
                << ")\n";
      return 2;
    }
    scenario.cameras.resize(static_cast<std::size_t>(cameras));
  }
  if (exposures > 0) scenario.num_exposures = std::min(exposures, scenario.num_exposures);

  try {
    std::filesystem::create_directories(out_dir);
    const sim::Simulator simulator(scenario, seed);
    camera::write_rig_calibration(simulator.true_rig(), out_dir + "/rig_true.json");
    if (mode == "boards") {
      sim_app::write_board_images(simulator, boards, seed, out_dir);
      return 0;
    }
    camera::write_rig_calibration(simulator.calibrated_rig(), out_dir + "/rig_calibrated.json");
    for (const survey::RigidBodySurvey& s : simulator.surveys()) {
      survey::write_survey(s, out_dir + "/survey_" + s.name + ".json");
    }
    survey::write_survey(simulator.true_pylon(), out_dir + "/true_survey_pylon.json");
    if (scenario.has_store()) {
      survey::write_survey(simulator.true_store(), out_dir + "/true_survey_store.json");
    }
    if (scenario.kind == sim::ScenarioKind::kScaleBars) {
      // The bar definition storetrack-eval lme reads (docs/evaluation.md).
      survey::write_scale_bars(simulator.scale_bar_set(false), out_dir + "/scale_bars.json");
      survey::write_scale_bars(simulator.scale_bar_set(true), out_dir + "/true_scale_bars.json");
    }
    write_registration(simulator, out_dir);
    sim::write_truth_csv(simulator, out_dir + "/truth_poses.csv", out_dir + "/truth_marks.csv");
    if (scenario.kind == sim::ScenarioKind::kPendulum)
      sim::write_pendulum_truth_json(simulator, out_dir + "/truth_pendulum.json");
    if (mode == "frames") {
      for (int c = 0; c < simulator.num_cameras(); ++c) {
        const int id = scenario.cameras[static_cast<std::size_t>(c)].camera_id;
        sim::write_frame_sequence(simulator, c, out_dir + "/frames/cam" + std::to_string(id));
        std::printf("camera %d: %d frames\n", id, simulator.num_exposures());
      }
    }
    write_observations(simulator, out_dir);
    std::printf("storetrack-sim: scenario %s (%s), %d cameras, %d exposures, seed %llu -> %s\n",
                scenario.name.c_str(), sim::to_string(scenario.kind), simulator.num_cameras(),
                simulator.num_exposures(), static_cast<unsigned long long>(seed), out_dir.c_str());
  } catch (const std::exception& e) {
    std::cerr << "storetrack-sim: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
