// libFuzzer target: the storetrack-host configuration reader (host/app parse_host_config, then
// finish_host_config against a 4-camera rig) on arbitrary text. Properties checked (abort when
// violated), beyond "no crash, no UB":
//  - a refusal is a HostConfigError naming the origin or the field; no other exception escapes;
//  - an accepted configuration holds every ranged value in its documented range
//    (docs/fti-output.md, "storetrack-host": udp.port, sources, aligner limits, store_id, ...);
//  - the ExposureAligner accepts the aligner part the reader accepted (one set of limits).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <string>

#include "host_config.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"

namespace {

namespace app = storetrack::hostapp;
namespace ingest = storetrack::ingest;

void check_ranges(const app::HostConfig& c) {
  if (c.udp_port < 0 || c.udp_port > 65535) std::abort();
  for (const auto& s : c.udp_sources)
    if (s.unit_id < 0 || s.unit_id > 254 || s.address.empty()) std::abort();
  const auto& a = c.aligner;
  if (!(a.max_wait_ns > 0 && a.max_wait_ns <= ingest::kMaxAlignerWaitNs)) std::abort();
  if (a.max_mid_time_spread_ns < 0 || a.max_mid_time_spread_ns > ingest::kMaxMidTimeSpreadNs)
    std::abort();
  if (a.max_pending < 1 || a.max_pending > ingest::kMaxAlignerPending) std::abort();
  if (a.min_cameras < 1 || a.max_sequence_lead < 1 ||
      a.max_sequence_lead > ingest::kMaxSequenceLead)
    std::abort();
  if (c.processor.store_id > 254) std::abort();
  if (!(c.processor.max_pose_rotation_sigma_rad > 0)) std::abort();
  const auto& m = c.processor.matcher;
  if (!(m.gate_probability > 0 && m.gate_probability < 1)) std::abort();
  if (!(c.initial_marks_sigma_m > 0)) std::abort();
  const auto& t = c.processor.pose_tracker;
  if (!(t.max_gap_s >= 0) || !(t.max_velocity_baseline_s > 0) || !(t.accel_sigma_m_s2 > 0) ||
      !(t.angular_accel_sigma_rad_s2 > 0) || !t.mean_accel_p_m_s2.allFinite())
    std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  app::HostConfig config;
  try {
    app::parse_host_config(text, "fuzz.json", config);
    check_ranges(config);
    app::finish_host_config(config, {0, 1, 2, 3}, {0, 0, 1, 1});
  } catch (const app::HostConfigError& e) {
    const std::string what = e.what();
    // The file's refusals start with the file; finish_host_config's with the key it checks
    // (udp.bind, aligner.min_cameras: values that may come from the command line).
    if (what.rfind("fuzz.json", 0) != 0 && what.rfind("udp.", 0) != 0 &&
        what.rfind("aligner.", 0) != 0)
      std::abort();
    return 0;
  }
  check_ranges(config);
  if (config.aligner.min_cameras > 4) std::abort();
  try {
    const ingest::ExposureAligner aligner(config.aligner);
    (void)aligner;
  } catch (const std::invalid_argument&) {
    std::abort();  // the reader accepted what the aligner refuses
  }
  return 0;
}
