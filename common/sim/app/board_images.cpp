// Board image set writer: plans the frames (common/sim board_set.hpp), renders every camera's
// view of every frame through the scenario's optics and sensor, writes 8-bit grey PNGs.
#include "board_images.hpp"

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <random>
#include <stdexcept>
#include <vector>

#include "storetrack/png/png_writer.hpp"
#include "storetrack/sim/frame_source.hpp"

namespace storetrack::sim_app {
namespace {

// PNG where the build has libpng (tools/install-deps.sh installs it), else PGM.
const char* extension() {
  return png::available() ? "png" : "pgm";
}

void write_image(const std::string& path, const std::vector<std::uint8_t>& gray, int width,
                 int height) {
  if (!png::available()) {
    if (sim::write_pgm(path, gray.data(), width, height, width) != 0)
      throw std::runtime_error(path + ": cannot write");
    return;
  }
  std::FILE* fp = std::fopen(path.c_str(), "wb");
  if (fp == nullptr) throw std::runtime_error(path + ": cannot open for writing");
  // Fast compression: the images are noisy, better levels gain little.
  const bool ok = png::write_png(fp, gray.data(), width, height, png::Channels::kGray, 1);
  if (std::fclose(fp) != 0 || !ok) throw std::runtime_error(path + ": PNG write failed");
}

std::string frame_name(int frame) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "frame_%04d.%s", frame, extension());
  return buf;
}

}  // namespace

void write_board_images(const sim::Simulator& simulator, const sim::BoardSetOptions& options,
                        std::uint64_t seed, const std::string& out_dir) {
  const camera::RigCalibration& rig = simulator.true_rig();
  const std::vector<sim::BoardFrame> frames = sim::plan_board_frames(rig, options, seed);
  const std::string dir = out_dir + "/boards";
  sim::BoardPhotometry photometry;
  photometry.sensor = simulator.scenario().optics.sensor;
  photometry.psf_sigma_px = simulator.scenario().optics.psf_sigma_px;
  sim::BoardExpectedImage expected;
  std::vector<std::uint8_t> gray;
  double render_s = 0;
  for (const camera::CalibratedCamera& cam : rig.cameras) {
    const std::string cam_dir = dir + "/cam" + std::to_string(cam.camera_id);
    std::filesystem::create_directories(cam_dir);
    int whole = 0;
    for (const sim::BoardFrame& f : frames) {
      const auto t0 = std::chrono::steady_clock::now();
      sim::render_board_expected(cam.model, sim::board_in_camera(cam, f), options.board, photometry,
                                 expected);
      gray.resize(expected.electrons.size());
      std::mt19937_64 rng(sim::board_image_seed(seed, f.frame, cam.camera_id));
      sim::expose(expected.electrons.data(), expected.width, photometry.sensor, rng, gray.data(),
                  expected.width, expected.height, expected.width);
      render_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      write_image(cam_dir + "/" + frame_name(f.frame), gray, expected.width, expected.height);
      for (int id : f.cameras_seeing)
        whole += id == cam.camera_id ? 1 : 0;
    }
    std::printf("camera %d: %zu board images, the whole board in %d\n", cam.camera_id,
                frames.size(), whole);
  }
  sim::write_board_truth_json(rig, options, frames, seed,
                              std::string("boards/cam<camera_id>/frame_NNNN.") + extension(),
                              dir + "/truth.json");
  std::printf("board set: %zu frames x %zu cameras, %.0f ms per image rendered + exposed\n",
              frames.size(), rig.cameras.size(),
              1e3 * render_s / static_cast<double>(frames.size() * rig.cameras.size()));
}

}  // namespace storetrack::sim_app
