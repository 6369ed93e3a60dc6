// The MarkObservations message of one exposure (common/msg/schema): who took it, when, and
// the marks as the wire carries them (8-bit peaks, known flags only). Fills a message the
// caller owns: no allocation.
#pragma once

#include <cstdint>
#include <span>
#include <string>

#include "storetrack/centroid/centroider.hpp"
#include "storetrack/frame/frame_source.hpp"
#include "storetrack/msg/messages.hpp"

namespace storetrack::unit {

/// The exposure as the message states it.
struct ExposureStamp {
  std::uint8_t unit_id = 0;
  std::uint8_t camera_id = 0;
  std::uint32_t trigger_seq = 0;
  time::MonotonicNs start_mono_ns = 0;
  std::int64_t start_tai_ns = 0;
  std::uint32_t duration_ns = 0;
  std::uint8_t clock_state = 0;
  std::uint32_t time_sigma_ns = 0;  ///< MarkObservations.exposure_time_sigma_ns
  std::uint16_t flags = 0;          ///< msg::exposure_flags
};

/// Whether every pixel centre of a frame this size is encodable (MarkObservations x_px, y_px);
/// else each exposure with a mark beyond would be lost. False with the reason in `why`.
bool frame_fits_message(int width, int height, std::string& why);

/// Fills `out` with the exposure and its marks (at most msg::kMaxMarks).
void fill_mark_message(const ExposureStamp& exposure, const frame::FrameView& frame,
                       std::span<const centroid::Blob> marks, msg::MarkObservations& out);

}  // namespace storetrack::unit
