// V4L2 pixel-format negotiation (pure logic over an IoctlOps, testable with a fake device).
//
// Preference: GREY (Y8) > Y16 > Y12 > Y10 (16-bit little-endian containers, LSB-aligned) >
// packed YUV 4:2:2 (YUYV, UYVY) from which only the luma plane is taken. The YUV fallback
// exists for devices (e.g. vivid in some inputs, UVC webcams) that offer no monochrome format:
// the Y samples of YUYV are the BT.601 luma the sensor produced, so taking every other byte is
// a lossless extraction of the grey image, not a colour conversion. It is used only when the
// device offers none of the monochrome formats.
#pragma once

#include <cstdint>
#include <span>
#include <string>

#include "storetrack/capture/xioctl.hpp"
#include "storetrack/frame/frame_source.hpp"

namespace storetrack::capture {

enum class Conversion : std::uint8_t {
  kNone,      ///< the buffer is handed out as is (GREY, Y10/Y12/Y16)
  kLumaYuyv,  ///< Y0 U Y1 V: luma at even bytes
  kLumaUyvy,  ///< U Y0 V Y1: luma at odd bytes
};

struct FormatChoice {
  std::uint32_t fourcc = 0;
  Conversion conversion = Conversion::kNone;
  frame::PixelFormat pixel_format = frame::PixelFormat::kMono8;
  int bits_per_pixel = 8;
  int width = 0;
  int height = 0;
  int bytes_per_line = 0;
  std::uint32_t size_image = 0;
};

/// "GREY", "Y16 ", ... for messages.
std::string fourcc_to_string(std::uint32_t fourcc);

/// Rank of a format in the preference list above (lower is better); -1 if unusable.
int format_rank(std::uint32_t fourcc);

/// Picks the best usable format among `offered` (pure). Returns false if none is usable.
bool choose_format(std::span<const std::uint32_t> offered, FormatChoice& out);

struct FormatRequest {
  int width = 1920;
  int height = 1024;
  bool allow_size_change = true;  ///< accept the driver's adjusted size (reported in *note)
};

/// Enumerates the device's capture formats (VIDIOC_ENUM_FMT), then tries them in preference
/// order with VIDIOC_S_FMT until the driver accepts one. Returns 0 or -errno; `error` names
/// what failed; `note` tells about adjustments (size changed, conversion in use).
int negotiate_format(const IoctlOps& ops, int fd, const FormatRequest& request, FormatChoice& out,
                     std::string& error, std::string& note);

}  // namespace storetrack::capture
