#include "storetrack/capture/v4l2_frame_source.hpp"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>

namespace storetrack::capture {
namespace {

// "Exposure Time, Absolute" and "exposure_time_absolute" compare equal.
std::string normalise(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (std::isalnum(static_cast<unsigned char>(c))) {
      out += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    }
  }
  return out;
}

}  // namespace

V4L2FrameSource::V4L2FrameSource(V4L2Config config, IoctlOps ops)
    : config_(std::move(config)), ops_(ops) {}

V4L2FrameSource::~V4L2FrameSource() {
  stop();
}

int V4L2FrameSource::fail(int rc, const std::string& what) {
  error_ = config_.device + ": " + what + (rc < 0 ? std::string(": ") + std::strerror(-rc) : "");
  return rc;
}

int V4L2FrameSource::find_control(const std::string& name, std::uint32_t& id) {
  const std::string wanted = normalise(name);
  v4l2_queryctrl q{};
  q.id = V4L2_CTRL_FLAG_NEXT_CTRL;
  while (ops_(fd_, VIDIOC_QUERYCTRL, &q) == 0) {
    if (!(q.flags & V4L2_CTRL_FLAG_DISABLED) && q.type != V4L2_CTRL_TYPE_CTRL_CLASS &&
        normalise(reinterpret_cast<const char*>(q.name)) == wanted) {
      id = q.id;
      return 0;
    }
    q.id |= V4L2_CTRL_FLAG_NEXT_CTRL;
  }
  return -ENOENT;
}

int V4L2FrameSource::set_control(const std::string& name, std::int32_t value,
                                 std::int32_t* applied) {
  if (fd_ < 0) return -EBADF;
  std::uint32_t id = 0;
  if (int rc = find_control(name, id); rc < 0) return fail(rc, "no control '" + name + "'");
  v4l2_control ctrl{};
  ctrl.id = id;
  ctrl.value = value;
  if (int rc = ops_(fd_, VIDIOC_S_CTRL, &ctrl); rc < 0) {
    return fail(rc, "VIDIOC_S_CTRL '" + name + "' = " + std::to_string(value));
  }
  if (applied != nullptr) *applied = ctrl.value;
  return 0;
}

int V4L2FrameSource::start() {
  if (streaming_) return 0;
  error_.clear();
  notes_.clear();
  fd_ = open(config_.device.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (fd_ < 0) return fail(-errno, "open");

  v4l2_capability cap{};
  if (int rc = ops_(fd_, VIDIOC_QUERYCAP, &cap); rc < 0) {
    fail(rc, "VIDIOC_QUERYCAP (not a V4L2 device?)");
    stop();
    return rc;
  }
  const std::uint32_t caps =
      (cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? cap.device_caps : cap.capabilities;
  if (!(caps & V4L2_CAP_VIDEO_CAPTURE) || !(caps & V4L2_CAP_STREAMING)) {
    fail(-ENODEV, std::string("'") + reinterpret_cast<const char*>(cap.card) +
                      "' has no single-planar video capture with streaming I/O");
    stop();
    return -ENODEV;
  }
  if (config_.input >= 0) {
    int input = config_.input;
    if (int rc = ops_(fd_, VIDIOC_S_INPUT, &input); rc < 0) {
      fail(rc, "VIDIOC_S_INPUT " + std::to_string(config_.input));
      stop();
      return rc;
    }
  }

  FormatRequest request;
  request.width = config_.width;
  request.height = config_.height;
  request.allow_size_change = config_.allow_size_change;
  std::string why;
  std::string note;
  if (int rc = negotiate_format(ops_, fd_, request, format_, why, note); rc < 0) {
    fail(rc, "format negotiation: " + why);
    stop();
    return rc;
  }
  notes_ = note;

  for (const V4L2Control& c : config_.controls) {
    const int rc = set_control(c.name, c.value);
    if (rc < 0) {
      if (c.required) {
        stop();
        return rc;
      }
      notes_ += std::string(notes_.empty() ? "" : "; ") + "optional control skipped: " + error_;
      error_.clear();
    }
  }

  v4l2_requestbuffers req{};
  req.count = static_cast<std::uint32_t>(std::clamp(config_.buffers, 2, 32));
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  if (int rc = ops_(fd_, VIDIOC_REQBUFS, &req); rc < 0) {
    fail(rc, "VIDIOC_REQBUFS (mmap)");
    stop();
    return rc;
  }
  if (req.count < 2) {
    fail(-ENOMEM, "driver granted only " + std::to_string(req.count) + " buffer(s)");
    stop();
    return -ENOMEM;
  }
  buffers_.resize(req.count);
  for (std::uint32_t i = 0; i < req.count; ++i) {
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    buf.index = i;
    if (int rc = ops_(fd_, VIDIOC_QUERYBUF, &buf); rc < 0) {
      fail(rc, "VIDIOC_QUERYBUF " + std::to_string(i));
      stop();
      return rc;
    }
    if (buf.length < frame_bytes()) {  // a frame would be read past the buffer's end
      fail(-EINVAL, "buffer " + std::to_string(i) + " is " + std::to_string(buf.length) +
                        " bytes, a frame of the format needs " + std::to_string(frame_bytes()));
      stop();
      return -EINVAL;
    }
    void* p = mmap(nullptr, buf.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, buf.m.offset);
    if (p == MAP_FAILED) {
      const int rc = -errno;
      fail(rc, "mmap buffer " + std::to_string(i));
      stop();
      return rc;
    }
    buffers_[i].data = p;
    buffers_[i].length = buf.length;
    if (format_.conversion != Conversion::kNone) {
      buffers_[i].luma.assign(static_cast<std::size_t>(format_.width * format_.height), 0);
    }
    if (int rc = queue(buf); rc < 0) {
      fail(rc, "VIDIOC_QBUF " + std::to_string(i));
      stop();
      return rc;
    }
  }
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (int rc = ops_(fd_, VIDIOC_STREAMON, &type); rc < 0) {
    fail(rc, "VIDIOC_STREAMON");
    stop();
    return rc;
  }
  streaming_ = true;
  have_sequence_ = false;
  return 0;
}

void V4L2FrameSource::unmap_all() {
  for (Buffer& b : buffers_) {
    if (b.data != nullptr) munmap(b.data, b.length);
  }
  buffers_.clear();
}

int V4L2FrameSource::stop() {
  if (fd_ < 0) return 0;
  if (streaming_) {
    int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    ops_(fd_, VIDIOC_STREAMOFF, &type);
    streaming_ = false;
  }
  unmap_all();
  queued_ = 0;
  v4l2_requestbuffers req{};  // count 0 frees the driver's buffers
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  ops_(fd_, VIDIOC_REQBUFS, &req);
  close(fd_);
  fd_ = -1;
  return 0;
}

std::size_t V4L2FrameSource::frame_bytes() const {
  return static_cast<std::size_t>(format_.bytes_per_line) *
         static_cast<std::size_t>(std::max(format_.height, 0));
}

int V4L2FrameSource::note_fault(const char* what, int rc) {
  fault_ = what;
  fault_errno_ = -rc;
  return rc;
}

int V4L2FrameSource::queue(v4l2_buffer& buf) {
  const int rc = ops_(fd_, VIDIOC_QBUF, &buf);
  if (rc == 0) ++queued_;
  return rc;
}

// A dequeued buffer whose frame is not usable goes back to the driver at once; the frame is lost
// (counted under `reason`), the caller gets -EBADMSG and keeps control (no loop here).
int V4L2FrameSource::give_back(v4l2_buffer& buf, std::atomic<std::uint64_t>& reason) {
  reason.fetch_add(1, std::memory_order_relaxed);
  buf.bytesused = 0;
  if (const int rc = queue(buf); rc < 0) {
    requeue_errors_.fetch_add(1, std::memory_order_relaxed);
    note_fault("VIDIOC_QBUF of a bad frame's buffer failed", rc);
  }
  return -EBADMSG;
}

// Forward gaps of the driver's sequence are dropped frames; a sequence that goes backwards (the
// driver restarted its count: a reopened stream, a reset sensor) is counted as a reset, never as
// ~2^32 drops.
void V4L2FrameSource::count_sequence(std::uint32_t sequence) {
  if (have_sequence_) {
    const auto gap = static_cast<std::int32_t>(sequence - last_sequence_ - 1);
    if (gap > 0)
      dropped_.fetch_add(static_cast<std::uint64_t>(gap), std::memory_order_relaxed);
    else if (gap < 0)
      sequence_resets_.fetch_add(1, std::memory_order_relaxed);
  }
  have_sequence_ = true;
  last_sequence_ = sequence;
}

int V4L2FrameSource::acquire(frame::FrameView& frame, int timeout_ms) {
  if (!streaming_) return -ENOTCONN;
  if (queued_ == 0) {  // every buffer lost to failed VIDIOC_QBUFs: nothing can ever arrive
    return note_fault("no buffer left in the driver's queue (VIDIOC_QBUF failures)", -EIO);
  }
  for (;;) {
    pollfd pfd{fd_, POLLIN, 0};
    int n;
    do {
      n = poll(&pfd, 1, timeout_ms);
    } while (n < 0 && errno == EINTR);
    if (n < 0) return -errno;
    if (n == 0) {
      timeouts_.fetch_add(1, std::memory_order_relaxed);
      return -EAGAIN;
    }
    if (pfd.revents & (POLLERR | POLLHUP | POLLNVAL)) {
      return note_fault("poll reported an error (device gone or streaming stopped)", -EIO);
    }
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    const int rc = ops_(fd_, VIDIOC_DQBUF, &buf);
    if (rc == -EAGAIN) continue;  // poll said readable, the buffer went elsewhere: wait again
    if (rc < 0) {
      note_fault("VIDIOC_DQBUF failed", rc);
      return -EIO;
    }
    --queued_;
    if (buf.index >= buffers_.size())  // a driver bug: no buffer of ours to give back
      return note_fault("VIDIOC_DQBUF returned a buffer index outside the ring", -EIO);
    if (buf.flags & V4L2_BUF_FLAG_ERROR) return give_back(buf, error_buffers_);
    // bytesused 0: drivers that do not fill it; else the whole image must be there.
    if (buf.bytesused != 0 && buf.bytesused < frame_bytes()) return give_back(buf, short_buffers_);
    count_sequence(buf.sequence);
    frames_.fetch_add(1, std::memory_order_relaxed);
    fill_view(buf, frame);
    return 0;
  }
}

void V4L2FrameSource::fill_view(const v4l2_buffer& buf, frame::FrameView& frame) {
  time::MonotonicNs ts;
  if ((buf.flags & V4L2_BUF_FLAG_TIMESTAMP_MASK) == V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC) {
    ts = static_cast<time::MonotonicNs>(buf.timestamp.tv_sec) * time::kNsPerSecond +
         static_cast<time::MonotonicNs>(buf.timestamp.tv_usec) * 1000;
  } else {
    ts = time::monotonic_now_ns();  // driver gives no monotonic stamp: DQBUF time
  }
  Buffer& b = buffers_[buf.index];
  frame.width = format_.width;
  frame.height = format_.height;
  frame.format = format_.pixel_format;
  frame.bits_per_pixel = format_.bits_per_pixel;
  frame.sequence = buf.sequence;
  frame.timestamp_mono_ns = ts - config_.timestamp_to_exposure_start_ns;
  frame.exposure_ns = config_.exposure_ns;
  frame.buffer_index = static_cast<int>(buf.index);
  const auto* src = static_cast<const std::uint8_t*>(b.data);
  if (format_.conversion == Conversion::kNone) {
    frame.pixels = src;
    frame.stride_bytes = format_.bytes_per_line;
    return;
  }
  const int first = format_.conversion == Conversion::kLumaYuyv ? 0 : 1;
  for (int y = 0; y < format_.height; ++y) {
    const std::uint8_t* row = src + static_cast<std::ptrdiff_t>(y) * format_.bytes_per_line;
    std::uint8_t* dst = b.luma.data() + static_cast<std::ptrdiff_t>(y) * format_.width;
    for (int x = 0; x < format_.width; ++x)
      dst[x] = row[2 * x + first];
  }
  frame.pixels = b.luma.data();
  frame.stride_bytes = format_.width;
}

int V4L2FrameSource::release(const frame::FrameView& frame) {
  if (!streaming_) return -ENOTCONN;
  if (frame.buffer_index < 0 || static_cast<std::size_t>(frame.buffer_index) >= buffers_.size()) {
    return -EINVAL;
  }
  v4l2_buffer buf{};
  buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  buf.memory = V4L2_MEMORY_MMAP;
  buf.index = static_cast<std::uint32_t>(frame.buffer_index);
  const int rc = queue(buf);
  if (rc < 0) {  // the buffer is out of the ring until the stream is restarted
    requeue_errors_.fetch_add(1, std::memory_order_relaxed);
    note_fault("VIDIOC_QBUF of a released buffer failed", rc);
  }
  return rc;
}

V4L2Stats V4L2FrameSource::stats() const {
  V4L2Stats s;
  s.frames = frames_.load();
  s.dropped = dropped_.load();
  s.error_buffers = error_buffers_.load();
  s.short_buffers = short_buffers_.load();
  s.requeue_errors = requeue_errors_.load();
  s.sequence_resets = sequence_resets_.load();
  s.timeouts = timeouts_.load();
  return s;
}

}  // namespace storetrack::capture
