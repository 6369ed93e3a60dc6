// Random message generators for the msg codec tests (values span each field's full wire range).
#pragma once

#include <cmath>
#include <cstdint>
#include <random>

#include "storetrack/msg/messages.hpp"

namespace storetrack::msg::test {

inline double uniform(std::mt19937_64& rng, double lo, double hi) {
  return std::uniform_real_distribution<double>(lo, hi)(rng);
}
template <typename T>
T any_int(std::mt19937_64& rng) {
  return static_cast<T>(rng());
}

inline MarkObservation random_mark(std::mt19937_64& rng) {
  MarkObservation o;
  o.x_px = static_cast<float>(uniform(rng, -0.5, 2047.49));
  o.y_px = static_cast<float>(uniform(rng, -0.5, 2047.49));
  o.sigma_px = static_cast<float>(0.001 * std::exp2(uniform(rng, 0.0, 15.8)));  // 0.001..55 px
  o.peak = static_cast<std::uint16_t>(rng() % 255 + 1);
  o.diameter_px = static_cast<float>(uniform(rng, 0.5, 31.5));
  o.flags = static_cast<std::uint8_t>(rng() & 0xF);
  return o;
}

inline MarkObservations random_observations(std::mt19937_64& rng, int mark_count = -1) {
  MarkObservations m;
  m.unit_id = any_int<std::uint8_t>(rng);
  m.camera_id = any_int<std::uint8_t>(rng);
  m.trigger_seq = any_int<std::uint32_t>(rng);
  m.exposure_start_tai_ns = any_int<std::int64_t>(rng);
  m.exposure_start_mono_ns = any_int<std::int64_t>(rng);
  m.exposure_duration_ns = any_int<std::uint32_t>(rng);
  m.clock_state = static_cast<std::uint8_t>(rng() % 4);
  m.flags = any_int<std::uint16_t>(rng);
  m.mark_count = static_cast<std::uint8_t>(mark_count >= 0 ? mark_count : rng() % (kMaxMarks + 1));
  for (std::size_t i = 0; i < m.mark_count; ++i)
    m.marks[i] = random_mark(rng);
  return m;
}

inline UnitHealth random_health(std::mt19937_64& rng) {
  UnitHealth h;
  h.unit_id = any_int<std::uint8_t>(rng);
  h.clock_state = static_cast<std::uint8_t>(rng() % 4);
  h.uptime_s = any_int<std::uint32_t>(rng);
  h.report_tai_ns = any_int<std::int64_t>(rng);
  h.ptp_offset_ns = any_int<std::int32_t>(rng);
  h.sensor_temp_cdeg = any_int<std::int16_t>(rng);
  h.board_temp_cdeg = any_int<std::int16_t>(rng);
  h.frames_captured = any_int<std::uint32_t>(rng);
  h.frames_dropped = any_int<std::uint32_t>(rng);
  h.triggers_seen = any_int<std::uint32_t>(rng);
  h.triggers_missing = any_int<std::uint32_t>(rng);
  h.triggers_extra = any_int<std::uint32_t>(rng);
  h.observations_sent = any_int<std::uint32_t>(rng);
  h.link_tx_errors = any_int<std::uint32_t>(rng);
  h.link_tx_dropped = any_int<std::uint32_t>(rng);
  h.can_bus_off_count = any_int<std::uint16_t>(rng);
  h.can_error_frames = any_int<std::uint16_t>(rng);
  h.centroid_time_us_max = any_int<std::uint16_t>(rng);
  h.status = any_int<std::uint16_t>(rng);
  return h;
}

}  // namespace storetrack::msg::test
