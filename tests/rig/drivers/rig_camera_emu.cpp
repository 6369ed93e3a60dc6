// rig_camera_emu: a triggered camera stand-in for the in-VM end-to-end test (guest/e2e.sh).
//
// vivid's capture side is free-running, so this program makes each frame exist BECAUSE of a
// trigger edge, as a camera in external-trigger mode does: it waits for rising edges on a GPIO
// line (libgpiod 1.6 edge events, kernel CLOCK_MONOTONIC time stamps) and, for the k-th edge,
// queues the simulator-rendered frame k of every camera into that camera's vivid OUTPUT device
// (V4L2 mmap streaming). vivid's loopback copies the output buffer at the head of its queue into
// the capture buffers it fills; with the output queue empty the capture shows the test pattern
// (set to black by the guest script), so between triggers the camera delivers dark frames.
//
// Each frame is queued --copies times (default 2): vivid's output thread retires one buffer per
// output frame period on its own phase, so a single buffer could be retired before the capture
// thread copied it. Two copies guarantee at least one capture of the frame; a second capture
// of the same frame is not claimed by any trigger edge at the unit (counted there).
//
// The next frames are read from disk while waiting for the edge, so an edge costs a memcpy and
// VIDIOC_QBUF. Every edge is logged (CSV): edge index, edge time, frame index, queue time.
//
//   rig_camera_emu --chip gpiochipN --line L --device /dev/video1 --frames DIR/cam0
//                  [--device /dev/video3 --frames DIR/cam1] --count N --log emu.csv
#include <fcntl.h>
#include <gpiod.h>
#include <linux/videodev2.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <string>
#include <vector>
#include "storetrack/cli/command_line.hpp"

#include "storetrack/sim/frame_source.hpp"

namespace {

std::int64_t mono_now_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return std::int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
}

int xioctl(int fd, unsigned long request, void* arg) {
  int rc;
  do {
    rc = ioctl(fd, request, arg);
  } while (rc < 0 && errno == EINTR);
  return rc;
}

// One vivid output device, mmap streaming, GREY.
class OutputDevice {
 public:
  ~OutputDevice() { close_device(); }

  bool open_device(const std::string& path, int buffers, std::string& error) {
    path_ = path;
    fd_ = open(path.c_str(), O_RDWR | O_NONBLOCK);
    if (fd_ < 0) return fail("open", error);
    v4l2_format fmt{};
    fmt.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    if (xioctl(fd_, VIDIOC_G_FMT, &fmt) < 0) return fail("VIDIOC_G_FMT", error);
    width_ = static_cast<int>(fmt.fmt.pix.width);
    height_ = static_cast<int>(fmt.fmt.pix.height);
    stride_ = static_cast<int>(fmt.fmt.pix.bytesperline);
    sizeimage_ = fmt.fmt.pix.sizeimage;
    if (fmt.fmt.pix.pixelformat != V4L2_PIX_FMT_GREY) {
      error = path + ": output format is not GREY (set it with v4l2-ctl first)";
      return false;
    }
    v4l2_requestbuffers req{};
    req.count = static_cast<unsigned>(buffers);
    req.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    req.memory = V4L2_MEMORY_MMAP;
    if (xioctl(fd_, VIDIOC_REQBUFS, &req) < 0) return fail("VIDIOC_REQBUFS", error);
    for (unsigned i = 0; i < req.count; ++i) {
      v4l2_buffer b{};
      b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
      b.memory = V4L2_MEMORY_MMAP;
      b.index = i;
      if (xioctl(fd_, VIDIOC_QUERYBUF, &b) < 0) return fail("VIDIOC_QUERYBUF", error);
      void* p = mmap(nullptr, b.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, b.m.offset);
      if (p == MAP_FAILED) return fail("mmap", error);
      maps_.push_back({static_cast<std::uint8_t*>(p), b.length, false});
    }
    return true;
  }

  // Queues `pixels` (w x h, tightly packed); rows beyond h are black. Takes a free buffer,
  // reclaiming retired ones first and waiting up to 2 s for one (edges served late, back to
  // back, can fill the queue faster than vivid's output retires one buffer per frame period).
  // false (+error) when none is free.
  bool queue(const std::uint8_t* pixels, int w, int h, std::string& error) {
    std::size_t index = maps_.size();
    for (int wait_ms = 0; index == maps_.size(); wait_ms += 10) {
      reclaim();
      for (std::size_t i = 0; i < maps_.size(); ++i) {
        if (!maps_[i].queued) {
          index = i;
          break;
        }
      }
      if (index != maps_.size()) break;
      if (wait_ms >= 2000) {
        error = path_ + ": no free output buffer for 2 s (vivid's output is not retiring them)";
        return false;
      }
      ++buffer_waits_;
      usleep(10'000);
    }
    Map& m = maps_[index];
    const int rows = pixels != nullptr ? std::min(h, height_) : 0;
    const int cols = std::min(w, width_);
    // Only what the frame does not cover is cleared: an edge should cost little more than a copy.
    const std::size_t covered = static_cast<std::size_t>(rows) * static_cast<std::size_t>(stride_);
    if (covered < sizeimage_) std::memset(m.data + covered, 0, sizeimage_ - covered);
    if (cols < stride_) {
      for (int y = 0; y < rows; ++y)
        std::memset(m.data + static_cast<std::size_t>(y) * static_cast<std::size_t>(stride_) + cols,
                    0, static_cast<std::size_t>(stride_ - cols));
    }
    for (int y = 0; y < rows; ++y) {
      std::memcpy(m.data + static_cast<std::size_t>(y) * static_cast<std::size_t>(stride_),
                  pixels + static_cast<std::size_t>(y) * static_cast<std::size_t>(w),
                  static_cast<std::size_t>(cols));
    }
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    b.memory = V4L2_MEMORY_MMAP;
    b.index = static_cast<unsigned>(index);
    b.bytesused = sizeimage_;
    if (xioctl(fd_, VIDIOC_QBUF, &b) < 0) return fail("VIDIOC_QBUF", error);
    m.queued = true;
    ++queued_;
    return true;
  }

  bool stream_on(std::string& error) {
    int type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    if (xioctl(fd_, VIDIOC_STREAMON, &type) < 0) return fail("VIDIOC_STREAMON", error);
    streaming_ = true;
    return true;
  }

  void reclaim() {
    for (;;) {
      v4l2_buffer b{};
      b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
      b.memory = V4L2_MEMORY_MMAP;
      if (xioctl(fd_, VIDIOC_DQBUF, &b) < 0) return;  // EAGAIN: none retired yet
      if (b.index < maps_.size()) maps_[b.index].queued = false;
      ++retired_;
    }
  }

  void close_device() {
    if (fd_ < 0) return;
    if (streaming_) {
      int type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
      xioctl(fd_, VIDIOC_STREAMOFF, &type);
    }
    for (const Map& m : maps_)
      munmap(m.data, m.length);
    maps_.clear();
    close(fd_);
    fd_ = -1;
  }

  int width() const { return width_; }
  int height() const { return height_; }
  std::uint64_t queued() const { return queued_; }
  std::uint64_t buffer_waits() const { return buffer_waits_; }
  std::uint64_t retired() const { return retired_; }

 private:
  struct Map {
    std::uint8_t* data;
    std::size_t length;
    bool queued;
  };
  bool fail(const char* what, std::string& error) {
    error = path_ + ": " + what + ": " + std::strerror(errno);
    return false;
  }
  std::string path_;
  int fd_ = -1;
  int width_ = 0, height_ = 0, stride_ = 0;
  std::uint32_t sizeimage_ = 0;
  bool streaming_ = false;
  std::vector<Map> maps_;
  std::uint64_t queued_ = 0, retired_ = 0, buffer_waits_ = 0;
};

struct Frame {
  std::vector<std::uint8_t> pixels;
  int width = 0, height = 0;
};

std::string frame_path(const std::string& dir, int k) {
  char name[32];
  std::snprintf(name, sizeof(name), "/frame_%06d.pgm", k);
  return dir + name;
}

}  // namespace

int main(int argc, char** argv) {
  storetrack::cli::Command app{
      "rig_camera_emu: triggered camera stand-in (GPIO edge -> frame into vivid output)"};
  std::string chip_name;
  unsigned line_offset = 0;
  std::vector<std::string> devices, frame_dirs;
  int count = 0, copies = 2, buffers = 16;
  double timeout_s = 10;
  std::string log_path;
  app.option("--chip", chip_name, "GPIO chip (name, path or label)").required();
  app.option("--line", line_offset, "Input line offset (rising edges = triggers)").required();
  app.option("--device", devices, "vivid output device, one per camera").required();
  app.option("--frames", frame_dirs, "Directory of frame_NNNNNN.pgm, one per --device").required();
  app.option("--count", count, "Edges to serve (frames 0..count-1)").required();
  app.option("--copies", copies, "Output buffers queued per frame").range(1, 3);
  app.option("--buffers", buffers, "Output buffers per device").range(4, 32);
  app.option("--timeout-s", timeout_s, "Give up after this long without an edge");
  app.option("--log", log_path, "CSV: edge,t_edge_mono_ns,frame,t_queued_mono_ns");
  if (const int rc = app.parse(argc, argv); rc >= 0) return rc;
  if (devices.size() != frame_dirs.size()) {
    std::fprintf(stderr, "rig_camera_emu: give one --frames per --device\n");
    return 2;
  }

  std::vector<OutputDevice> outputs(devices.size());
  std::string error;
  for (std::size_t c = 0; c < devices.size(); ++c) {
    if (!outputs[c].open_device(devices[c], buffers, error)) {
      std::fprintf(stderr, "rig_camera_emu: %s\n", error.c_str());
      return 1;
    }
  }
  // vivid starts streaming only once two buffers are queued: pre-roll two black frames, which
  // the output thread retires within two frame periods; the queue then stays empty (black
  // capture) until the first trigger.
  for (auto& o : outputs) {
    for (int i = 0; i < 2; ++i) {
      if (!o.queue(nullptr, 0, 0, error)) {
        std::fprintf(stderr, "rig_camera_emu: %s\n", error.c_str());
        return 1;
      }
    }
    if (!o.stream_on(error)) {
      std::fprintf(stderr, "rig_camera_emu: %s\n", error.c_str());
      return 1;
    }
  }

  gpiod_chip* chip = gpiod_chip_open_lookup(chip_name.c_str());
  if (chip == nullptr) {
    std::fprintf(stderr, "rig_camera_emu: cannot open GPIO chip %s: %s\n", chip_name.c_str(),
                 std::strerror(errno));
    return 1;
  }
  gpiod_line* line = gpiod_chip_get_line(chip, line_offset);
  if (line == nullptr || gpiod_line_request_rising_edge_events(line, "rig-camera-emu") < 0) {
    std::fprintf(stderr, "rig_camera_emu: cannot request %s line %u for edges: %s\n",
                 chip_name.c_str(), line_offset, std::strerror(errno));
    gpiod_chip_close(chip);
    return 1;
  }
  std::FILE* log = log_path.empty() ? nullptr : std::fopen(log_path.c_str(), "w");
  if (log != nullptr) std::fprintf(log, "edge,t_edge_mono_ns,frame,t_queued_mono_ns\n");
  std::printf("rig_camera_emu: ready, %zu camera(s), waiting for %d edges on %s line %u\n",
              devices.size(), count, chip_name.c_str(), line_offset);
  std::fflush(stdout);

  std::vector<Frame> next(devices.size());
  auto load = [&](int k) -> bool {
    for (std::size_t c = 0; c < devices.size(); ++c) {
      try {
        next[c].pixels =
            storetrack::sim::read_pgm(frame_path(frame_dirs[c], k), next[c].width, next[c].height);
      } catch (const std::exception& e) {
        std::fprintf(stderr, "rig_camera_emu: %s\n", e.what());
        return false;
      }
    }
    return true;
  };
  int rc = 0;
  int served = 0;
  std::int64_t max_reaction_ns = 0;
  if (!load(0)) rc = 1;
  while (rc == 0 && served < count) {
    timespec timeout{static_cast<time_t>(timeout_s), 0};
    const int w = gpiod_line_event_wait(line, &timeout);
    if (w < 0) {
      std::fprintf(stderr, "rig_camera_emu: edge wait: %s\n", std::strerror(errno));
      rc = 1;
      break;
    }
    if (w == 0) {
      std::fprintf(stderr, "rig_camera_emu: no edge for %.0f s after %d edges\n", timeout_s,
                   served);
      rc = 1;
      break;
    }
    gpiod_line_event ev{};
    if (gpiod_line_event_read(line, &ev) < 0) {
      std::fprintf(stderr, "rig_camera_emu: edge read: %s\n", std::strerror(errno));
      rc = 1;
      break;
    }
    const std::int64_t t_edge = std::int64_t{ev.ts.tv_sec} * 1'000'000'000 + ev.ts.tv_nsec;
    for (std::size_t c = 0; c < outputs.size() && rc == 0; ++c) {
      for (int i = 0; i < copies; ++i) {
        if (!outputs[c].queue(next[c].pixels.data(), next[c].width, next[c].height, error)) {
          std::fprintf(stderr, "rig_camera_emu: edge %d: %s\n", served, error.c_str());
          rc = 1;
          break;
        }
      }
    }
    const std::int64_t t_queued = mono_now_ns();
    max_reaction_ns = std::max(max_reaction_ns, t_queued - t_edge);
    if (log != nullptr) {
      std::fprintf(log, "%d,%lld,%d,%lld\n", served, static_cast<long long>(t_edge), served,
                   static_cast<long long>(t_queued));
      std::fflush(log);
    }
    ++served;
    if (rc == 0 && served < count && !load(served)) rc = 1;
  }
  // Let the last frames reach the capture side before the outputs stop.
  usleep(300'000);
  for (auto& o : outputs)
    o.reclaim();
  std::printf("rig_camera_emu: %d edges served, max reaction %.1f ms", served,
              static_cast<double>(max_reaction_ns) / 1e6);
  for (std::size_t c = 0; c < outputs.size(); ++c) {
    std::printf(", %s %llu queued / %llu retired (%llu waits for a buffer)", devices[c].c_str(),
                static_cast<unsigned long long>(outputs[c].queued()),
                static_cast<unsigned long long>(outputs[c].retired()),
                static_cast<unsigned long long>(outputs[c].buffer_waits()));
  }
  std::printf("\n");
  if (log != nullptr) std::fclose(log);
  gpiod_line_release(line);
  gpiod_chip_close(chip);
  return rc;
}
