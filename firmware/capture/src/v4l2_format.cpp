#include "storetrack/capture/v4l2_format.hpp"

#include <linux/videodev2.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstring>
#include <vector>

namespace storetrack::capture {
namespace {

struct FormatInfo {
  std::uint32_t fourcc;
  Conversion conversion;
  frame::PixelFormat pixel_format;
  int bits;
};

// Preference order (index = rank).
constexpr std::array<FormatInfo, 6> kFormats{{
    {V4L2_PIX_FMT_GREY, Conversion::kNone, frame::PixelFormat::kMono8, 8},
    {V4L2_PIX_FMT_Y16, Conversion::kNone, frame::PixelFormat::kMono16, 16},
    {V4L2_PIX_FMT_Y12, Conversion::kNone, frame::PixelFormat::kMono16, 12},
    {V4L2_PIX_FMT_Y10, Conversion::kNone, frame::PixelFormat::kMono16, 10},
    {V4L2_PIX_FMT_YUYV, Conversion::kLumaYuyv, frame::PixelFormat::kMono8, 8},
    {V4L2_PIX_FMT_UYVY, Conversion::kLumaUyvy, frame::PixelFormat::kMono8, 8},
}};

}  // namespace

std::string fourcc_to_string(std::uint32_t f) {
  std::string s(4, ' ');
  for (int i = 0; i < 4; ++i) {
    const char c = static_cast<char>((f >> (8 * i)) & 0xFF);
    s[static_cast<std::size_t>(i)] = (c >= 32 && c < 127) ? c : '?';
  }
  return s;
}

int format_rank(std::uint32_t fourcc) {
  for (std::size_t i = 0; i < kFormats.size(); ++i) {
    if (kFormats[i].fourcc == fourcc) return static_cast<int>(i);
  }
  return -1;
}

bool choose_format(std::span<const std::uint32_t> offered, FormatChoice& out) {
  int best = -1;
  for (std::uint32_t f : offered) {
    const int r = format_rank(f);
    if (r >= 0 && (best < 0 || r < best)) best = r;
  }
  if (best < 0) return false;
  const FormatInfo& info = kFormats[static_cast<std::size_t>(best)];
  out.fourcc = info.fourcc;
  out.conversion = info.conversion;
  out.pixel_format = info.pixel_format;
  out.bits_per_pixel = info.bits;
  return true;
}

int negotiate_format(const IoctlOps& ops, int fd, const FormatRequest& request, FormatChoice& out,
                     std::string& error, std::string& note) {
  std::vector<std::uint32_t> offered;
  for (std::uint32_t index = 0; index < 256; ++index) {
    v4l2_fmtdesc desc{};
    desc.index = index;
    desc.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    const int rc = ops(fd, VIDIOC_ENUM_FMT, &desc);
    if (rc == -EINVAL) break;  // end of the list
    if (rc < 0) {
      error = std::string("VIDIOC_ENUM_FMT failed: ") + std::strerror(-rc);
      return rc;
    }
    offered.push_back(desc.pixelformat);
  }
  std::string offered_text;
  for (std::uint32_t f : offered) {
    if (!offered_text.empty()) offered_text += ',';
    offered_text += fourcc_to_string(f);
  }

  // Try the usable formats best-first: a driver may list a format but refuse it at this size.
  std::vector<std::uint32_t> candidates;
  for (std::uint32_t f : offered) {
    if (format_rank(f) >= 0) candidates.push_back(f);
  }
  std::sort(candidates.begin(), candidates.end(),
            [](std::uint32_t a, std::uint32_t b) { return format_rank(a) < format_rank(b); });
  candidates.erase(std::unique(candidates.begin(), candidates.end()), candidates.end());
  if (candidates.empty()) {
    error = "no usable pixel format (need GREY, Y16, Y12, Y10, YUYV or UYVY); device offers: " +
            offered_text;
    return -ENOTSUP;
  }
  int last_rc = -EINVAL;
  for (std::uint32_t f : candidates) {
    v4l2_format fmt{};
    fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    fmt.fmt.pix.width = static_cast<std::uint32_t>(request.width);
    fmt.fmt.pix.height = static_cast<std::uint32_t>(request.height);
    fmt.fmt.pix.pixelformat = f;
    fmt.fmt.pix.field = V4L2_FIELD_NONE;
    const int rc = ops(fd, VIDIOC_S_FMT, &fmt);
    if (rc < 0) {
      last_rc = rc;
      continue;
    }
    if (fmt.fmt.pix.pixelformat != f) continue;  // driver substituted another format
    if (fmt.fmt.pix.field != V4L2_FIELD_NONE && fmt.fmt.pix.field != V4L2_FIELD_ANY) {
      last_rc = -EINVAL;
      continue;  // interlaced: not a usable measurement image
    }
    const std::uint32_t std_fourcc[] = {f};
    choose_format(std_fourcc, out);
    out.width = static_cast<int>(fmt.fmt.pix.width);
    out.height = static_cast<int>(fmt.fmt.pix.height);
    const int bytes_per_pixel = out.conversion != Conversion::kNone
                                    ? 2
                                    : (out.pixel_format == frame::PixelFormat::kMono8 ? 1 : 2);
    out.bytes_per_line = static_cast<int>(fmt.fmt.pix.bytesperline);
    if (out.bytes_per_line < out.width * bytes_per_pixel)
      out.bytes_per_line = out.width * bytes_per_pixel;
    out.size_image = fmt.fmt.pix.sizeimage;
    if (out.size_image < static_cast<std::uint32_t>(out.bytes_per_line * out.height)) {
      out.size_image = static_cast<std::uint32_t>(out.bytes_per_line * out.height);
    }
    note.clear();
    if (out.width != request.width || out.height != request.height) {
      const std::string msg = "driver set " + std::to_string(out.width) + "x" +
                              std::to_string(out.height) + " instead of " +
                              std::to_string(request.width) + "x" + std::to_string(request.height);
      if (!request.allow_size_change) {
        error = msg;
        return -ERANGE;
      }
      note = msg;
    }
    if (out.conversion != Conversion::kNone) {
      note += std::string(note.empty() ? "" : "; ") + "no monochrome format offered (" +
              offered_text + "): taking luma from " + fourcc_to_string(f);
    }
    return 0;
  }
  error =
      "VIDIOC_S_FMT refused every usable format (" + offered_text + "): " + std::strerror(-last_rc);
  return last_rc;
}

}  // namespace storetrack::capture
