// Board image set writer: plans the frames (common/sim board_set.hpp), renders every camera's
// view of every frame through the scenario's optics and sensor, writes 8-bit grey PNGs.
#include "board_images.hpp"

#include <chrono>
#include <csetjmp>
#include <cstdio>
#include <filesystem>
#include <random>
#include <stdexcept>
#include <vector>

#ifdef STORETRACK_HAVE_PNG
#include <png.h>
#endif

#include "storetrack/sim/frame_source.hpp"

namespace storetrack::sim_app {
namespace {

#ifdef STORETRACK_HAVE_PNG
constexpr const char* kExtension = "png";

// libpng reports errors by longjmp back into this frame: it holds no C++ object with a
// destructor between setjmp and the libpng calls.
bool write_png_gray(std::FILE* fp, const std::uint8_t* gray, int width, int height) {
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (png == nullptr || info == nullptr || setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return false;
  }
  png_init_io(png, fp);
  png_set_compression_level(png, 1);  // fast: the images are noisy, better levels gain little
  png_set_IHDR(png, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height), 8,
               PNG_COLOR_TYPE_GRAY, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  for (int y = 0; y < height; ++y)
    png_write_row(png, gray + static_cast<std::size_t>(y) * static_cast<std::size_t>(width));
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return true;
}

void write_png(const std::string& path, const std::vector<std::uint8_t>& gray, int width,
               int height) {
  std::FILE* fp = std::fopen(path.c_str(), "wb");
  if (fp == nullptr) throw std::runtime_error(path + ": cannot open for writing");
  const bool ok = write_png_gray(fp, gray.data(), width, height);
  if (std::fclose(fp) != 0 || !ok) throw std::runtime_error(path + ": PNG write failed");
}
#else
constexpr const char* kExtension = "pgm";

void write_png(const std::string& path, const std::vector<std::uint8_t>& gray, int width,
               int height) {
  if (sim::write_pgm(path, gray.data(), width, height, width) != 0)
    throw std::runtime_error(path + ": cannot write");
}
#endif

std::string frame_name(int frame) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "frame_%04d.%s", frame, kExtension);
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
      write_png(cam_dir + "/" + frame_name(f.frame), gray, expected.width, expected.height);
      for (int id : f.cameras_seeing)
        whole += id == cam.camera_id ? 1 : 0;
    }
    std::printf("camera %d: %zu board images, the whole board in %d\n", cam.camera_id,
                frames.size(), whole);
  }
  sim::write_board_truth_json(rig, options, frames, seed,
                              std::string("boards/cam<camera_id>/frame_NNNN.") + kExtension,
                              dir + "/truth.json");
  std::printf("board set: %zu frames x %zu cameras, %.0f ms per image rendered + exposed\n",
              frames.size(), rig.cameras.size(),
              1e3 * render_s / static_cast<double>(frames.size() * rig.cameras.size()));
}

}  // namespace storetrack::sim_app
