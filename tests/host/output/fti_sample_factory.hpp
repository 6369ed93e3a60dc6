// Deterministic, varied FtiSamples for the output tests.
#pragma once

#include <cmath>
#include <random>

#include "storetrack/msg/messages.hpp"

namespace storetrack::output::testing {

inline msg::FtiSample make_sample(std::uint32_t k, std::int64_t t0_tai_ns, std::mt19937_64& rng,
                                  std::uint8_t store_id = 1) {
  std::normal_distribution<float> n(0.0f, 1.0f);
  msg::FtiSample s{};
  s.store_id = store_id;
  s.cameras_used = static_cast<std::uint8_t>(2 + k % 3);
  s.marks_used = static_cast<std::uint8_t>(8 + k % 9);
  s.pylon_marks_used = 7;
  s.trigger_seq = 5000 + k;
  s.exposure_mid_tai_ns = t0_tai_ns + static_cast<std::int64_t>(k) * 2'500'000 + 250'000;
  s.x_m = 0.01f * static_cast<float>(k) + n(rng);
  s.y_m = n(rng);
  s.z_m = 0.5f * n(rng);
  s.yaw_rad = 0.1f * n(rng);
  s.pitch_rad = -0.2f * n(rng);
  s.roll_rad = 0.3f * n(rng);
  s.u_x_m = 1e-4f * (1 + std::abs(n(rng)));
  s.u_y_m = 2e-4f;
  s.u_z_m = 3e-4f;
  s.u_yaw_rad = 1e-3f;
  s.u_pitch_rad = 2e-3f;
  s.u_roll_rad = 3e-3f;
  for (int i = 0; i < 15; ++i)
    s.correlation[i] = std::tanh(n(rng));
  s.u_budget_centroid_m = 5e-5f;
  s.u_budget_intrinsic_m = 6e-5f;
  s.u_budget_extrinsic_m = 7e-5f;
  s.u_budget_sync_m = 8e-6f;
  // Extrapolated-like samples carry a process-noise part, measured-like ones 0 (both on the wire).
  s.u_budget_process_m = (k % 3 == 0) ? 0.0f : 1e-4f * static_cast<float>(1 + k % 7);
  s.coverage_factor = 2.0f;
  // Clearance (block version 3): every 5th sample without a geometry (invalid), no rng draw so
  // the other fields' sequences stay those of version 2.
  const bool clearance = k % 5 != 0;
  s.clearance_m = clearance ? 0.25f + 0.001f * static_cast<float>(k) : NAN;
  s.u_clearance_m = clearance ? 3e-4f : NAN;
  s.clearance_lower_bound_m = clearance ? s.clearance_m - 6e-4f : NAN;
  s.clearance_part = clearance ? static_cast<std::uint16_t>(k % 3) : 0xFFFF;
  s.status = (k % 17 == 0) ? 0 : msg::fti_status::kValid;
  return s;
}

}  // namespace storetrack::output::testing
