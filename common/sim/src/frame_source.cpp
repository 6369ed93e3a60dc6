#include "storetrack/sim/frame_source.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <random>
#include <stdexcept>

namespace storetrack::sim {

namespace {
constexpr std::size_t kMaxBoxesPerFrame = 1024;  // reserved: the per-frame path never allocates
constexpr std::size_t kUnitNormals = std::size_t{1} << 20;
}  // namespace

SimFrameSource::SimFrameSource(const Simulator& sim, int camera_index, int ring_size,
                               bool pace_realtime, int first_exposure, double pace_hz,
                               int background_pool)
    : sim_(sim),
      camera_index_(camera_index),
      pace_(pace_realtime),
      first_exposure_(std::max(first_exposure, 0)),
      next_exposure_(first_exposure_),
      background_pool_(std::max(background_pool, 0)) {
  pace_hz_ = pace_hz > 0 ? pace_hz : sim.scenario().frame_rate_hz;
  if (camera_index < 0 || camera_index >= sim.num_cameras()) {
    throw std::invalid_argument("SimFrameSource: camera index " + std::to_string(camera_index) +
                                " out of range");
  }
  const camera::Intrinsics& in =
      sim.true_rig().cameras[static_cast<std::size_t>(camera_index)].model.intrinsics();
  width_ = in.width;
  height_ = in.height;
  ring_size = background_pool_ > 0 ? background_pool_ : std::max(ring_size, 1);
  pacing_.frame_period_ns = 1e9 / pace_hz_;
  buffers_.assign(static_cast<std::size_t>(ring_size),
                  std::vector<std::uint8_t>(static_cast<std::size_t>(width_) * height_));
  held_.assign(static_cast<std::size_t>(ring_size), false);
  name_ = "sim camera " +
          std::to_string(sim.scenario().cameras[static_cast<std::size_t>(camera_index)].camera_id);
}

int SimFrameSource::start() {
  if (started_) return -EALREADY;
  // Warm the renderer's scratch memory so the per-frame path does not allocate.
  sim_.render_into(0, camera_index_, buffers_[0].data(), width_, renderer_);
  std::vector<Spot> warm;
  sim_.spots(0, camera_index_, warm);
  if (background_pool_ > 0) {
    std::mt19937_64 rng(0x5eed0000u + static_cast<unsigned>(camera_index_));
    std::normal_distribution<float> normal(0.0f, 1.0f);
    unit_normals_.resize(kUnitNormals);
    for (float& z : unit_normals_)
      z = normal(rng);
    backgrounds_.resize(buffers_.size());
    drawn_.assign(buffers_.size(), {});
    for (std::size_t i = 0; i < buffers_.size(); ++i) {
      sim_.render_background_into(static_cast<int>(i), camera_index_, buffers_[i].data(), width_,
                                  renderer_);
      backgrounds_[i] = buffers_[i];
      drawn_[i].reserve(kMaxBoxesPerFrame);
    }
    sim_.render_spots_into(0, camera_index_, buffers_[0].data(), width_, renderer_, unit_normals_);
    buffers_[0] = backgrounds_[0];
  }
  started_ = true;
  start_mono_ns_ = time::monotonic_now_ns();
  return 0;
}

int SimFrameSource::stop() {
  if (!started_) return -EINVAL;
  started_ = false;
  return 0;
}

int SimFrameSource::acquire(frame::FrameView& frame, int timeout_ms) {
  if (!started_) return -EINVAL;
  if (next_exposure_ >= sim_.num_exposures()) return -ENODATA;
  const int k = next_exposure_;
  std::size_t slot =
      background_pool_ > 0 ? static_cast<std::size_t>(k) % buffers_.size() : buffers_.size();
  for (std::size_t i = 0; i < buffers_.size() && background_pool_ == 0; ++i) {
    if (!held_[i]) {
      slot = i;
      break;
    }
  }
  if (slot == buffers_.size() || held_[slot]) return -EBUSY;
  time::MonotonicNs due = 0;
  if (pace_) {
    due = pace_origin_ns_ != 0
              ? pace_origin_ns_ + std::llround(k * 1e9 / pace_hz_)
              : start_mono_ns_ + std::llround((k - first_exposure_) * 1e9 / pace_hz_);
    const time::MonotonicNs now = time::monotonic_now_ns();
    if (due - now > static_cast<std::int64_t>(timeout_ms) * 1'000'000) return -EAGAIN;
    if (due > now) {
      timespec ts{static_cast<time_t>((due - now) / time::kNsPerSecond),
                  static_cast<long>((due - now) % time::kNsPerSecond)};
      nanosleep(&ts, nullptr);
    }
  }
  if (background_pool_ > 0) {
    render_pooled(k, slot);
  } else {
    sim_.render_into(k, camera_index_, buffers_[slot].data(), width_, renderer_);
  }
  if (pace_) {
    const std::int64_t behind = time::monotonic_now_ns() - due;
    pacing_.max_behind_ns = std::max(pacing_.max_behind_ns, behind);
    if (static_cast<double>(behind) > pacing_.frame_period_ns) ++pacing_.frames_late;
  }
  held_[slot] = true;
  const ExposureTiming t = sim_.exposure_timing(k, camera_index_);
  frame.pixels = buffers_[slot].data();
  frame.width = width_;
  frame.height = height_;
  frame.stride_bytes = width_;
  frame.format = frame::PixelFormat::kMono8;
  frame.bits_per_pixel = 8;
  frame.sequence = t.trigger_seq;
  frame.timestamp_mono_ns = t.reported_start_mono_ns;
  frame.exposure_ns = t.exposure_ns;
  frame.buffer_index = static_cast<int>(slot);
  ++next_exposure_;
  return 0;
}

// Puts back the background under the spots last drawn in this buffer, then draws exposure k's.
void SimFrameSource::render_pooled(int k, std::size_t slot) {
  std::vector<std::uint8_t>& image = buffers_[slot];
  const std::vector<std::uint8_t>& background = backgrounds_[slot];
  for (const PixelBox& box : drawn_[slot]) {
    for (int y = box.y0; y < box.y1; ++y) {
      const std::size_t row = static_cast<std::size_t>(y) * static_cast<std::size_t>(width_);
      std::copy(background.begin() + static_cast<std::ptrdiff_t>(row + box.x0),
                background.begin() + static_cast<std::ptrdiff_t>(row + box.x1),
                image.begin() + static_cast<std::ptrdiff_t>(row + box.x0));
    }
  }
  sim_.render_spots_into(k, camera_index_, image.data(), width_, renderer_, unit_normals_);
  const auto boxes = renderer_.drawn_boxes();
  if (boxes.size() <= kMaxBoxesPerFrame) {
    drawn_[slot].assign(boxes.begin(), boxes.end());
  } else {  // more boxes than tracked: the whole frame is put back next time
    drawn_[slot].assign(1, PixelBox{0, 0, width_, height_});
  }
}

int SimFrameSource::release(const frame::FrameView& frame) {
  if (frame.buffer_index < 0 || frame.buffer_index >= static_cast<int>(buffers_.size()) ||
      !held_[static_cast<std::size_t>(frame.buffer_index)]) {
    return -EINVAL;
  }
  held_[static_cast<std::size_t>(frame.buffer_index)] = false;
  return 0;
}

int write_pgm(const std::string& path, const std::uint8_t* pixels, int width, int height,
              int stride) {
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return -errno;
  int rc = 0;
  if (std::fprintf(f, "P5\n%d %d\n255\n", width, height) < 0) rc = -EIO;
  for (int y = 0; y < height && rc == 0; ++y) {
    if (std::fwrite(pixels + static_cast<std::size_t>(y) * stride, 1,
                    static_cast<std::size_t>(width), f) != static_cast<std::size_t>(width)) {
      rc = -EIO;
    }
  }
  if (std::fclose(f) != 0 && rc == 0) rc = -EIO;
  return rc;
}

std::vector<std::uint8_t> read_pgm(const std::string& path, int& width, int& height) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open PGM");
  std::string magic;
  int maxval = 0;
  in >> magic >> width >> height >> maxval;
  if (!in || magic != "P5" || width <= 0 || height <= 0 || width > 16384 || height > 16384 ||
      maxval != 255) {
    throw std::runtime_error(path + ": not an 8-bit binary PGM (P5, maxval 255)");
  }
  in.get();  // the single whitespace after maxval
  std::vector<std::uint8_t> pixels(static_cast<std::size_t>(width) * height);
  in.read(reinterpret_cast<char*>(pixels.data()), static_cast<std::streamsize>(pixels.size()));
  if (in.gcount() != static_cast<std::streamsize>(pixels.size())) {
    throw std::runtime_error(path + ": truncated PGM pixel data");
  }
  return pixels;
}

void write_frame_sequence(const Simulator& sim, int camera_index, const std::string& dir,
                          int count) {
  std::filesystem::create_directories(dir);
  const int n = count < 0 ? sim.num_exposures() : std::min(count, sim.num_exposures());
  std::ofstream triggers(dir + "/triggers.csv");
  if (!triggers) throw std::runtime_error(dir + "/triggers.csv: cannot open for writing");
  triggers << "frame,trigger_seq,trigger_tai_ns,reported_start_tai_ns,reported_start_mono_ns,"
              "exposure_ns,true_exposure_start_tai_ns,file\n";
  SimFrameSource source(sim, camera_index, 1);
  if (source.start() != 0) throw std::runtime_error("SimFrameSource: start failed");
  for (int k = 0; k < n; ++k) {
    frame::FrameView view;
    const int rc = source.acquire(view, 0);
    if (rc != 0) throw std::runtime_error("SimFrameSource: acquire failed");
    char file[64];
    std::snprintf(file, sizeof file, "frame_%06d.pgm", k);
    if (write_pgm(dir + "/" + file, view.pixels, view.width, view.height, view.stride_bytes) != 0) {
      throw std::runtime_error(dir + "/" + file + ": write failed");
    }
    const ExposureTiming t = sim.exposure_timing(k, camera_index);
    triggers << k << "," << t.trigger_seq << "," << t.trigger_tai_ns << ","
             << t.reported_start_tai_ns << "," << t.reported_start_mono_ns << "," << t.exposure_ns
             << "," << t.true_start_tai_ns << "," << file << "\n";
    source.release(view);
  }
  if (!triggers) throw std::runtime_error(dir + "/triggers.csv: write failed");
}

}  // namespace storetrack::sim
