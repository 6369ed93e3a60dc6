// The observations the aligner tests feed in: what a healthy unit sends for one exposure of a
// 400 fps rig (one mark, a locked clock, a monotonic clock 7 s behind TAI).
#pragma once

#include <cstdint>

#include "storetrack/msg/messages.hpp"
#include "storetrack/time/saturating.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::ingest::test {

constexpr std::int64_t kPeriodNs = 2'500'000;  // 400 fps
constexpr std::int64_t kT0Tai = 1'800'000'000'000'000'000;

/// Camera `camera_id` of unit `unit_id`, exposure `seq` starting at `start_tai` [ns]; its one
/// mark at (camera_id, seq mod 1000) px, so a test can tell whose observation it got back.
inline msg::MarkObservations make_observation(int unit_id, int camera_id, std::uint32_t seq,
                                              std::int64_t start_tai) {
  msg::MarkObservations o{};
  o.unit_id = static_cast<std::uint8_t>(unit_id);
  o.camera_id = static_cast<std::uint8_t>(camera_id);
  o.trigger_seq = seq;
  o.exposure_start_tai_ns = start_tai;
  o.exposure_start_mono_ns = time::saturating_sub_ns(start_tai, 7 * time::kNsPerSecond);
  o.exposure_duration_ns = 500'000;
  o.clock_state = 2;
  o.mark_count = 1;
  o.marks[0].x_px = static_cast<float>(camera_id);
  o.marks[0].y_px = static_cast<float>(seq % 1000);
  return o;
}

}  // namespace storetrack::ingest::test
