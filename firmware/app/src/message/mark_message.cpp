#include "message/mark_message.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace storetrack::unit {

bool frame_fits_message(int width, int height, std::string& why) {
  namespace word = msg::mark_observation_word;
  const auto max_width = static_cast<int>(std::floor(word::kXPxMaxValue)) + 1;
  const auto max_height = static_cast<int>(std::floor(word::kYPxMaxValue)) + 1;
  if (width <= max_width && height <= max_height) return true;
  char line[256];
  std::snprintf(line, sizeof line,
                "sensor %d x %d px: mark coordinates are encodable only up to %.2f x %.2f px "
                "(MarkObservations x_px, y_px), i.e. frames of at most %d x %d px",
                width, height, word::kXPxMaxValue, word::kYPxMaxValue, max_width, max_height);
  why = line;
  return false;
}

void fill_mark_message(const ExposureStamp& exposure, const frame::FrameView& frame,
                       std::span<const centroid::Blob> marks, msg::MarkObservations& out) {
  out.unit_id = exposure.unit_id;
  out.camera_id = exposure.camera_id;
  out.trigger_seq = exposure.trigger_seq;
  out.exposure_start_mono_ns = exposure.start_mono_ns;
  out.exposure_start_tai_ns = exposure.start_tai_ns;
  out.exposure_duration_ns = exposure.duration_ns;
  out.clock_state = exposure.clock_state;
  out.exposure_time_sigma_ns = exposure.time_sigma_ns;
  out.flags = exposure.flags;
  out.mark_count = static_cast<std::uint8_t>(marks.size());
  // The wire's peak is 8-bit: a deeper pixel's peak is scaled down to it.
  const int shift = frame.format == frame::PixelFormat::kMono16 ? frame.bits_per_pixel - 8 : 0;
  for (std::size_t i = 0; i < marks.size(); ++i) {
    const centroid::Blob& b = marks[i];
    msg::MarkObservation& m = out.marks[i];
    m.x_px = static_cast<float>(b.x_px);
    m.y_px = static_cast<float>(b.y_px);
    m.sigma_px = static_cast<float>(b.sigma_px);
    const float peak8 = shift > 0 ? b.peak_dn / static_cast<float>(1 << shift) : b.peak_dn;
    m.peak = static_cast<std::uint16_t>(std::clamp(peak8, 0.0f, 255.0f));
    m.diameter_px = b.diameter_px;
    m.flags = b.flags & msg::mark_flags::kAllKnown;
  }
}

}  // namespace storetrack::unit
