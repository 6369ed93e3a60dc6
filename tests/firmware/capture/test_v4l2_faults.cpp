// V4L2FrameSource's streaming path under the faults a camera in a pylon shows (issue 12,
// "Camera"): buffers the driver flags V4L2_BUF_FLAG_ERROR, frames shorter than the image, a
// VIDIOC_QBUF that fails, a driver sequence that goes backwards, buffers too small for the
// format, a failing VIDIOC_DQBUF. The device is a scripted fake ioctl layer over /dev/zero (its
// poll() is always readable and MAP_SHARED mmap of it gives real memory), so acquire() runs its
// real poll + mmap path; vivid's own error injection is the VM rig's part (tests/rig).
#include <gtest/gtest.h>
#include <linux/videodev2.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <deque>

#include "storetrack/capture/v4l2_frame_source.hpp"

namespace storetrack::capture {
namespace {

constexpr int kWidth = 64, kHeight = 32;
constexpr std::uint32_t kImageBytes = kWidth * kHeight;

// One dequeue the script hands out: which buffer, its sequence, flags, bytes used, or an error.
struct Dequeue {
  std::uint32_t sequence = 0;
  std::uint32_t flags = V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC;
  std::uint32_t bytesused = kImageBytes;
  int error = 0;  // > 0: VIDIOC_DQBUF fails with this errno
};

struct ScriptedCamera {
  std::deque<Dequeue> script;
  std::deque<std::uint32_t> queued;  // buffer indices the "driver" holds, in QBUF order
  std::uint32_t buffer_length = kImageBytes;
  int qbuf_failures = 0;  // the next this many VIDIOC_QBUF calls fail with EIO
  int qbuf_calls = 0;

  static int call(void* ctx, int /*fd*/, unsigned long req, void* arg) {
    return static_cast<ScriptedCamera*>(ctx)->handle(req, arg);
  }
  int handle(unsigned long req, void* arg) {
    switch (req) {
      case VIDIOC_QUERYCAP: {
        auto* cap = static_cast<v4l2_capability*>(arg);
        cap->capabilities = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
        return 0;
      }
      case VIDIOC_ENUM_FMT: {
        auto* d = static_cast<v4l2_fmtdesc*>(arg);
        if (d->index > 0) return -EINVAL;
        d->pixelformat = V4L2_PIX_FMT_GREY;
        return 0;
      }
      case VIDIOC_S_FMT:
      case VIDIOC_G_FMT: {
        auto* f = static_cast<v4l2_format*>(arg);
        f->fmt.pix.pixelformat = V4L2_PIX_FMT_GREY;
        f->fmt.pix.width = kWidth;
        f->fmt.pix.height = kHeight;
        f->fmt.pix.bytesperline = kWidth;
        f->fmt.pix.sizeimage = kImageBytes;
        f->fmt.pix.field = V4L2_FIELD_NONE;
        return 0;
      }
      case VIDIOC_REQBUFS:
        return 0;  // grants what was asked (count 0 at stop)
      case VIDIOC_QUERYBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        b->length = buffer_length;
        b->m.offset = b->index * static_cast<std::uint32_t>(sysconf(_SC_PAGESIZE)) * 4;
        return 0;
      }
      case VIDIOC_QBUF: {
        ++qbuf_calls;
        if (qbuf_failures > 0) {
          --qbuf_failures;
          return -EIO;
        }
        queued.push_back(static_cast<v4l2_buffer*>(arg)->index);
        return 0;
      }
      case VIDIOC_DQBUF: {
        if (script.empty() || queued.empty()) return -EAGAIN;
        const Dequeue d = script.front();
        script.pop_front();
        if (d.error > 0) return -d.error;
        auto* b = static_cast<v4l2_buffer*>(arg);
        b->index = queued.front();
        queued.pop_front();
        b->sequence = d.sequence;
        b->flags = d.flags;
        b->bytesused = d.bytesused;
        return 0;
      }
      case VIDIOC_STREAMON:
      case VIDIOC_STREAMOFF:
        return 0;
      default:
        return -ENOTTY;
    }
  }
  IoctlOps ops() { return IoctlOps{&ScriptedCamera::call, this}; }
};

V4L2Config config() {
  V4L2Config c;
  c.device = "/dev/zero";
  c.width = kWidth;
  c.height = kHeight;
  c.buffers = 4;
  return c;
}

TEST(V4L2Faults, ErrorFlaggedAndShortBuffersAreGivenBackAndReturnedNotLoopedOn) {
  // Before: a buffer flagged V4L2_BUF_FLAG_ERROR made acquire() requeue and wait again inside
  // its own loop (a camera streaming only bad frames never returned: no health, no stop), and
  // bytesused was never looked at.
  ScriptedCamera cam;
  cam.script = {{0}, {1, V4L2_BUF_FLAG_ERROR}, {2, V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC, 100}, {3}};
  V4L2FrameSource src(config(), cam.ops());
  ASSERT_EQ(src.start(), 0) << src.error();
  frame::FrameView f;
  ASSERT_EQ(src.acquire(f, 100), 0);
  EXPECT_EQ(f.sequence, 0u);
  EXPECT_EQ(src.release(f), 0);
  EXPECT_EQ(src.acquire(f, 100), -EBADMSG) << "the flagged frame";
  EXPECT_EQ(src.acquire(f, 100), -EBADMSG) << "100 of 2048 bytes";
  ASSERT_EQ(src.acquire(f, 100), 0);
  EXPECT_EQ(f.sequence, 3u);
  EXPECT_EQ(src.release(f), 0);
  const V4L2Stats s = src.stats();
  EXPECT_EQ(s.frames, 2u);
  EXPECT_EQ(s.error_buffers, 1u);
  EXPECT_EQ(s.short_buffers, 1u);
  EXPECT_EQ(s.dropped, 2u) << "sequences 1 and 2 never reached the caller";
  EXPECT_EQ(cam.queued.size(), 4u) << "every buffer back in the driver's queue";
}

TEST(V4L2Faults, FailedRequeuesAreCountedAndAnEmptyRingIsADeviceError) {
  // Before: the results of VIDIOC_QBUF in acquire() and release() were ignored; each failure
  // silently took a buffer out of the ring until none was left and acquire() timed out for ever.
  ScriptedCamera cam;
  for (std::uint32_t k = 0; k < 8; ++k)
    cam.script.push_back({k});
  V4L2FrameSource src(config(), cam.ops());
  ASSERT_EQ(src.start(), 0) << src.error();
  cam.qbuf_failures = 100;
  frame::FrameView f;
  for (int k = 0; k < 4; ++k) {
    ASSERT_EQ(src.acquire(f, 100), 0) << k;
    EXPECT_EQ(src.release(f), -EIO);
  }
  EXPECT_EQ(src.stats().requeue_errors, 4u);
  EXPECT_EQ(src.acquire(f, 100), -EIO) << "no buffer left: the caller must restart the stream";
  EXPECT_STRNE(src.last_fault(), "");
  EXPECT_EQ(src.last_fault_errno(), EIO);
  // stop() + start() (what the unit does with a backoff) brings the ring back.
  cam.qbuf_failures = 0;
  src.stop();
  cam.queued.clear();
  ASSERT_EQ(src.start(), 0);
  EXPECT_EQ(cam.queued.size(), 4u);
  ASSERT_EQ(src.acquire(f, 100), 0);
  EXPECT_EQ(f.sequence, 4u);
}

TEST(V4L2Faults, BackwardsSequenceIsAResetNotFourBillionDrops) {
  // Before: sequence 7 after 9 added 7 - 9 - 1 = 2^32 - 3 to the dropped-frame counter.
  ScriptedCamera cam;
  cam.script = {{8}, {9}, {2}, {3}, {5}};
  V4L2FrameSource src(config(), cam.ops());
  ASSERT_EQ(src.start(), 0) << src.error();
  frame::FrameView f;
  for (int k = 0; k < 5; ++k) {
    ASSERT_EQ(src.acquire(f, 100), 0);
    src.release(f);
  }
  const V4L2Stats s = src.stats();
  EXPECT_EQ(s.sequence_resets, 1u);
  EXPECT_EQ(s.dropped, 1u) << "only sequence 4";
}

TEST(V4L2Faults, BufferSmallerThanTheImageIsRefusedAtStart) {
  // Before: buf.length was never compared with bytes_per_line x height: the centroider would
  // read past the mapping.
  ScriptedCamera cam;
  cam.buffer_length = kImageBytes - 1;
  V4L2FrameSource src(config(), cam.ops());
  EXPECT_EQ(src.start(), -EINVAL);
  EXPECT_NE(src.error().find("needs 2048"), std::string::npos) << src.error();
}

TEST(V4L2Faults, FailingDequeueIsADeviceError) {
  ScriptedCamera cam;
  cam.script = {{0}, {0, 0, 0, ENODEV}};
  V4L2FrameSource src(config(), cam.ops());
  ASSERT_EQ(src.start(), 0) << src.error();
  frame::FrameView f;
  ASSERT_EQ(src.acquire(f, 100), 0);
  src.release(f);
  EXPECT_EQ(src.acquire(f, 100), -EIO);
  EXPECT_EQ(src.last_fault_errno(), ENODEV);
}

}  // namespace
}  // namespace storetrack::capture
