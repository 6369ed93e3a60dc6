#include "health_history.hpp"

#include <cinttypes>

namespace storetrack::post {

void HealthHistory::observe(const pipeline::CalibrationHealthGuard& guard,
                            std::uint32_t trigger_seq, std::int64_t t_tai_ns) {
  const auto& cameras = guard.monitor().cameras();
  windows_seen_.resize(cameras.size(), 0);
  for (std::size_t s = 0; s < cameras.size(); ++s) {
    const pipeline::CameraHealth& h = cameras[s];
    if (h.windows_tested == windows_seen_[s]) continue;
    windows_seen_[s] = h.windows_tested;
    rows_.push_back({trigger_seq, t_tai_ns, h.camera_id, h.windows_tested, h.last_statistic,
                     guard.monitor().threshold(), h.moved});
  }
}

bool write_health_csv(std::FILE* f, std::span<const HealthWindowRow> rows) {
  bool ok =
      std::fputs("trigger_seq,t_tai_ns,camera_id,window,statistic,threshold,alarm,moved\n", f) >= 0;
  for (const HealthWindowRow& r : rows)
    ok = ok && std::fprintf(f, "%" PRIu32 ",%" PRId64 ",%d,%" PRIu64 ",%.6g,%.6g,%d,%d\n",
                            r.trigger_seq, r.t_tai_ns, r.camera_id, r.window, r.statistic,
                            r.threshold, r.statistic > r.threshold ? 1 : 0, r.moved ? 1 : 0) > 0;
  return ok;
}

}  // namespace storetrack::post
