// V4L2FrameSource: a real camera through Video4Linux2 (mmap streaming I/O).
//
// start(): open, VIDIOC_QUERYCAP (capture + streaming), format negotiation (v4l2_format.hpp),
// optional device controls (external-trigger mode, exposure) looked up by name, VIDIOC_REQBUFS
// + QUERYBUF + mmap of a buffer ring, QBUF all, STREAMON. acquire(): poll + VIDIOC_DQBUF; the
// frame view points INTO the mmap'd driver buffer (no copy) unless the device could only give
// packed YUV, in which case the luma is extracted into a buffer allocated at start().
// release(): VIDIOC_QBUF. Buffer sequence gaps are counted as dropped frames.
//
// Errors are -errno; error() says which device and what failed. A frame the driver flagged
// V4L2_BUF_FLAG_ERROR, or shorter than the format's image, is given back and acquire() returns
// -EBADMSG (one lost frame; the caller goes on). A device that is gone (POLLERR/POLLHUP, a
// failed VIDIOC_DQBUF, every buffer lost to failed VIDIOC_QBUFs) returns -EIO and stays so until
// stop() + start() reopen it (the unit does that with a backoff, firmware/app).
#pragma once

#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "storetrack/capture/v4l2_format.hpp"
#include "storetrack/capture/xioctl.hpp"
#include "storetrack/frame/frame_source.hpp"

struct v4l2_buffer;

namespace storetrack::capture {

struct V4L2Control {
  std::string name;  ///< as listed by `v4l2-ctl -l` / VIDIOC_QUERYCTRL ("Exposure Time, Absolute"
                     ///< or the snake-case id name "exposure_time_absolute"); case-insensitive
  std::int32_t value = 0;
  bool required = false;  ///< fail start() if the device lacks it (else a note is recorded)
};

struct V4L2Config {
  std::string device = "/dev/video0";
  int width = 1920;
  int height = 1024;
  bool allow_size_change = true;
  int buffers = 6;
  std::uint32_t exposure_ns = 1'000'000;  ///< reported in FrameView::exposure_ns
  /// What the driver's buffer time stamp marks relative to the exposure start: for
  /// V4L2_BUF_FLAG_TSTAMP_SRC_SOE 0; for end-of-frame stamps exposure + readout. Subtracted.
  std::int64_t timestamp_to_exposure_start_ns = 0;
  /// Controls set after the format, e.g. external trigger mode on industrial cameras.
  std::vector<V4L2Control> controls;
  int input = -1;  ///< VIDIOC_S_INPUT index (vivid: 2 for the looped-back output), -1: keep
};

struct V4L2Stats {
  std::uint64_t frames = 0;
  std::uint64_t dropped = 0;          ///< sequence gaps
  std::uint64_t error_buffers = 0;    ///< buffers flagged V4L2_BUF_FLAG_ERROR (requeued)
  std::uint64_t short_buffers = 0;    ///< bytesused below the format's image size (requeued)
  std::uint64_t requeue_errors = 0;   ///< VIDIOC_QBUF failed: that buffer is out of the ring
  std::uint64_t sequence_resets = 0;  ///< driver sequence went backwards (not counted as drops)
  std::uint64_t timeouts = 0;
};

class V4L2FrameSource final : public frame::FrameSource {
 public:
  explicit V4L2FrameSource(V4L2Config config, IoctlOps ops = real_ioctl_ops());
  ~V4L2FrameSource() override;
  V4L2FrameSource(const V4L2FrameSource&) = delete;
  V4L2FrameSource& operator=(const V4L2FrameSource&) = delete;

  int start() override;
  int stop() override;
  int acquire(frame::FrameView& frame, int timeout_ms) override;
  int release(const frame::FrameView& frame) override;
  const char* name() const override { return config_.device.c_str(); }

  /// Why start() or set_control() failed.
  const std::string& error() const { return error_; }
  /// The last fault while streaming (a static text, set without allocating) and its errno.
  const char* last_fault() const { return fault_; }
  int last_fault_errno() const { return fault_errno_; }
  /// Notes from start(): size adjusted, conversion in use, missing optional controls.
  const std::string& notes() const { return notes_; }
  const FormatChoice& format() const { return format_; }
  V4L2Stats stats() const;
  /// Sets a control by name while streaming (exposure from the Modbus configuration). A driver
  /// may clamp an out-of-range value instead of refusing it (VIDIOC_S_CTRL allows either): the
  /// value it set is returned in *applied when given.
  int set_control(const std::string& name, std::int32_t value, std::int32_t* applied = nullptr);
  /// The exposure the frames report from now on (after the exposure control changed it).
  void set_reported_exposure_ns(std::uint32_t ns) { config_.exposure_ns = ns; }

 private:
  struct Buffer {
    void* data = nullptr;
    std::size_t length = 0;
    std::vector<std::uint8_t> luma;  ///< only with a YUV conversion
  };
  int fail(int rc, const std::string& what);
  int find_control(const std::string& name, std::uint32_t& id);
  void unmap_all();
  int note_fault(const char* what, int rc);
  int queue(v4l2_buffer& buf);
  int give_back(v4l2_buffer& buf, std::atomic<std::uint64_t>& reason);
  void count_sequence(std::uint32_t sequence);
  void fill_view(const v4l2_buffer& buf, frame::FrameView& frame);
  std::size_t frame_bytes() const;

  V4L2Config config_;
  IoctlOps ops_;
  int fd_ = -1;
  bool streaming_ = false;
  FormatChoice format_;
  std::vector<Buffer> buffers_;
  std::string error_;
  std::string notes_;
  bool have_sequence_ = false;
  std::uint32_t last_sequence_ = 0;
  std::atomic<std::uint64_t> frames_{0};
  std::atomic<std::uint64_t> dropped_{0};
  std::atomic<std::uint64_t> error_buffers_{0};
  std::atomic<std::uint64_t> short_buffers_{0};
  std::atomic<std::uint64_t> requeue_errors_{0};
  std::atomic<std::uint64_t> sequence_resets_{0};
  std::atomic<std::uint64_t> timeouts_{0};
  const char* fault_ = "";
  int fault_errno_ = 0;
  std::size_t queued_ = 0;  // buffers the driver holds; 0 while streaming: nothing can arrive
};

}  // namespace storetrack::capture
