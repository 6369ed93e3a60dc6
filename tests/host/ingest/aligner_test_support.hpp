// What the aligner tests share: the observation a healthy unit sends for one exposure of a
// 400 fps rig (one mark, a locked clock, a monotonic clock 7 s behind TAI), the sum of the
// aligner's drop counters, and how often an observation was released.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include <gtest/gtest.h>

#include "storetrack/ingest/exposure_aligner.hpp"

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

/// Every observation the aligner dropped, whatever the cause.
inline std::uint64_t total_dropped(const AlignerCounters& c) {
  return c.dropped_unknown_camera + c.dropped_spoofed + c.dropped_invalid +
         c.dropped_time_out_of_range + c.dropped_duplicate + c.dropped_late +
         c.dropped_time_mismatch + c.dropped_quarantined + c.dropped_too_few_cameras +
         c.dropped_numbering_unknown;
}

/// Nothing lost silently: each observation pushed was used or counted as dropped.
inline void expect_every_observation_accounted(const AlignerCounters& c) {
  EXPECT_EQ(c.observations_in, c.observations_used + total_dropped(c));
}

/// How many released observations carry sequence `seq` (of camera `camera_id`, or any camera).
inline int times_released(const std::vector<pipeline::AlignedExposure>& out, std::uint32_t seq,
                          std::optional<int> camera_id = std::nullopt) {
  int n = 0;
  for (const auto& e : out)
    for (const auto& o : e.cameras)
      n += o.trigger_seq == seq && (!camera_id || o.camera_id == *camera_id) ? 1 : 0;
  return n;
}

}  // namespace storetrack::ingest::test
