// V4L2 format negotiation against a fake ioctl layer (pure logic only; the real driver path is
// exercised against vivid in the VM rig).
#include <gtest/gtest.h>
#include <linux/videodev2.h>

#include <cerrno>
#include <cstdint>
#include <set>
#include <vector>

#include "storetrack/capture/v4l2_format.hpp"

namespace storetrack::capture {
namespace {

struct FakeDevice {
  std::vector<std::uint32_t> offered;
  std::set<std::uint32_t> refused;  // S_FMT returns EINVAL for these
  int max_width = 4096;
  int max_height = 4096;
  int enum_error = 0;
  std::vector<std::uint32_t> s_fmt_calls;

  static int call(void* ctx, int /*fd*/, unsigned long req, void* arg) {
    auto* d = static_cast<FakeDevice*>(ctx);
    if (req == VIDIOC_ENUM_FMT) {
      auto* desc = static_cast<v4l2_fmtdesc*>(arg);
      if (d->enum_error != 0) return -d->enum_error;
      if (desc->type != V4L2_BUF_TYPE_VIDEO_CAPTURE) return -EINVAL;
      if (desc->index >= d->offered.size()) return -EINVAL;
      desc->pixelformat = d->offered[desc->index];
      return 0;
    }
    if (req == VIDIOC_S_FMT) {
      auto* f = static_cast<v4l2_format*>(arg);
      d->s_fmt_calls.push_back(f->fmt.pix.pixelformat);
      if (d->refused.count(f->fmt.pix.pixelformat)) return -EINVAL;
      bool known = false;
      for (auto o : d->offered)
        known = known || o == f->fmt.pix.pixelformat;
      if (!known) f->fmt.pix.pixelformat = d->offered.front();  // drivers substitute
      f->fmt.pix.width = std::min<std::uint32_t>(f->fmt.pix.width, d->max_width);
      f->fmt.pix.height = std::min<std::uint32_t>(f->fmt.pix.height, d->max_height);
      const std::uint32_t bpp = f->fmt.pix.pixelformat == V4L2_PIX_FMT_GREY ? 1 : 2;
      f->fmt.pix.bytesperline = f->fmt.pix.width * bpp;
      f->fmt.pix.sizeimage = f->fmt.pix.bytesperline * f->fmt.pix.height;
      f->fmt.pix.field = V4L2_FIELD_NONE;
      return 0;
    }
    return -ENOTTY;
  }
  IoctlOps ops() { return IoctlOps{&FakeDevice::call, this}; }
};

int negotiate(FakeDevice& d, FormatChoice& c, std::string& err, std::string& note,
              bool allow_size = true) {
  FormatRequest r;
  r.width = 1920;
  r.height = 1024;
  r.allow_size_change = allow_size;
  return negotiate_format(d.ops(), 3, r, c, err, note);
}

TEST(V4L2Format, PrefersGreyOverEverything) {
  FakeDevice d;
  d.offered = {V4L2_PIX_FMT_YUYV, V4L2_PIX_FMT_Y16, V4L2_PIX_FMT_GREY, V4L2_PIX_FMT_RGB24};
  FormatChoice c;
  std::string err, note;
  ASSERT_EQ(negotiate(d, c, err, note), 0) << err;
  EXPECT_EQ(c.fourcc, V4L2_PIX_FMT_GREY);
  EXPECT_EQ(c.conversion, Conversion::kNone);
  EXPECT_EQ(c.pixel_format, frame::PixelFormat::kMono8);
  EXPECT_EQ(c.width, 1920);
  EXPECT_EQ(c.height, 1024);
  EXPECT_EQ(c.bytes_per_line, 1920);
  EXPECT_TRUE(note.empty()) << note;
}

TEST(V4L2Format, Y16BeforeY10AndNoConversion) {
  FakeDevice d;
  d.offered = {V4L2_PIX_FMT_Y10, V4L2_PIX_FMT_Y16};
  FormatChoice c;
  std::string err, note;
  ASSERT_EQ(negotiate(d, c, err, note), 0) << err;
  EXPECT_EQ(c.fourcc, V4L2_PIX_FMT_Y16);
  EXPECT_EQ(c.pixel_format, frame::PixelFormat::kMono16);
  EXPECT_EQ(c.bits_per_pixel, 16);
  d.offered = {V4L2_PIX_FMT_Y10, V4L2_PIX_FMT_YUYV};
  ASSERT_EQ(negotiate(d, c, err, note), 0) << err;
  EXPECT_EQ(c.fourcc, V4L2_PIX_FMT_Y10);
  EXPECT_EQ(c.bits_per_pixel, 10);
}

TEST(V4L2Format, YuyvOnlyWhenNoMonochromeFormat) {
  FakeDevice d;
  d.offered = {V4L2_PIX_FMT_RGB24, V4L2_PIX_FMT_YUYV};
  FormatChoice c;
  std::string err, note;
  ASSERT_EQ(negotiate(d, c, err, note), 0) << err;
  EXPECT_EQ(c.fourcc, V4L2_PIX_FMT_YUYV);
  EXPECT_EQ(c.conversion, Conversion::kLumaYuyv);
  EXPECT_EQ(c.pixel_format, frame::PixelFormat::kMono8);
  EXPECT_NE(note.find("luma"), std::string::npos) << note;
}

TEST(V4L2Format, FallsBackWhenDriverRefusesBestFormat) {
  FakeDevice d;
  d.offered = {V4L2_PIX_FMT_GREY, V4L2_PIX_FMT_Y16};
  d.refused = {V4L2_PIX_FMT_GREY};
  FormatChoice c;
  std::string err, note;
  ASSERT_EQ(negotiate(d, c, err, note), 0) << err;
  EXPECT_EQ(c.fourcc, V4L2_PIX_FMT_Y16);
  EXPECT_EQ(d.s_fmt_calls.size(), 2u);
}

TEST(V4L2Format, SizeAdjustmentIsReportedOrRefused) {
  FakeDevice d;
  d.offered = {V4L2_PIX_FMT_GREY};
  d.max_width = 1280;
  d.max_height = 720;
  FormatChoice c;
  std::string err, note;
  ASSERT_EQ(negotiate(d, c, err, note), 0);
  EXPECT_EQ(c.width, 1280);
  EXPECT_NE(note.find("1280x720"), std::string::npos) << note;
  EXPECT_EQ(negotiate(d, c, err, note, /*allow_size=*/false), -ERANGE);
  EXPECT_NE(err.find("1280x720"), std::string::npos) << err;
}

TEST(V4L2Format, NoUsableFormatNamesWhatTheDeviceOffers) {
  FakeDevice d;
  d.offered = {V4L2_PIX_FMT_RGB24, V4L2_PIX_FMT_MJPEG};
  FormatChoice c;
  std::string err, note;
  EXPECT_EQ(negotiate(d, c, err, note), -ENOTSUP);
  EXPECT_NE(err.find("RGB3"), std::string::npos) << err;
  EXPECT_NE(err.find("MJPG"), std::string::npos) << err;
}

TEST(V4L2Format, EnumerationErrorIsPropagated) {
  FakeDevice d;
  d.offered = {V4L2_PIX_FMT_GREY};
  d.enum_error = EIO;
  FormatChoice c;
  std::string err, note;
  EXPECT_EQ(negotiate(d, c, err, note), -EIO);
  EXPECT_NE(err.find("VIDIOC_ENUM_FMT"), std::string::npos);
}

TEST(V4L2Format, PureChoiceRanksFormats) {
  FormatChoice c;
  const std::uint32_t none[] = {V4L2_PIX_FMT_RGB24};
  EXPECT_FALSE(choose_format(none, c));
  const std::uint32_t some[] = {V4L2_PIX_FMT_UYVY, V4L2_PIX_FMT_Y12};
  ASSERT_TRUE(choose_format(some, c));
  EXPECT_EQ(c.fourcc, V4L2_PIX_FMT_Y12);
  EXPECT_EQ(fourcc_to_string(V4L2_PIX_FMT_GREY), "GREY");
}

}  // namespace
}  // namespace storetrack::capture
