// libFuzzer target: the ExposureAligner (host/ingest) fed arbitrary decoded MarkObservations: the
// fuzz input chooses a valid configuration, then a sequence of observations (near a trigger grid
// or anywhere: foreign cameras, spoofed units, forged or restarted sequences, clock jumps, invalid
// fields) interleaved with host time steps and polls. Properties checked (abort when violated):
//  - accounting: after flush(), observations_in = observations_used + every dropped_* counter,
//    nothing is pending or held, and the observations in the released exposures are exactly
//    observations_used;
//  - nothing released twice: each pushed observation (tagged) appears in at most one released
//    exposure, and one camera's observation of one exposure (camera, trigger_seq, start time) is
//    used at most once;
//  - each released exposure is well formed: at least min_cameras, each a rig camera at most once,
//    missing_camera_mask = the rig cameras absent, a mid-time;
//  - bounds: pending() <= max_pending, held() <= cameras; after poll(now) nothing is overdue.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <set>
#include <tuple>
#include <vector>

#include <fuzzer/FuzzedDataProvider.h>

#include "storetrack/ingest/exposure_aligner.hpp"

namespace {

namespace ingest = storetrack::ingest;
namespace msg = storetrack::msg;
using storetrack::pipeline::AlignedExposure;

constexpr std::int64_t kPeriodNs = 2'500'000;  // 400 fps
constexpr std::int64_t kStartTaiNs = 1'700'000'000'000'000'000;
constexpr std::size_t kTagMark = msg::kMaxMarks - 1;  // the aligner never reads marks

ingest::AlignerConfig make_config(FuzzedDataProvider& in) {
  ingest::AlignerConfig c;
  const int cameras = in.ConsumeIntegralInRange(1, 6);
  const bool check_units = in.ConsumeBool();
  for (int i = 0; i < cameras; ++i) {
    c.camera_ids.push_back(10 + 3 * i);
    if (check_units) c.unit_ids.push_back(i / 2);
  }
  c.max_wait_ns = in.ConsumeIntegralInRange<std::int64_t>(1, ingest::kMaxAlignerWaitNs);
  c.max_mid_time_spread_ns =
      in.ConsumeIntegralInRange<std::int64_t>(0, ingest::kMaxMidTimeSpreadNs);
  c.max_pending = in.ConsumeIntegralInRange<std::size_t>(1, 64);
  c.min_cameras = in.ConsumeIntegralInRange(1, cameras);
  c.max_sequence_lead = in.ConsumeIntegralInRange<std::uint32_t>(1, ingest::kMaxSequenceLead);
  return c;
}

// Mostly plausible (a camera of the rig near the trigger grid), sometimes anything.
msg::MarkObservations make_observation(FuzzedDataProvider& in, const ingest::AlignerConfig& c,
                                       std::uint32_t serial) {
  msg::MarkObservations o;
  const std::size_t cam = in.ConsumeIntegralInRange<std::size_t>(0, c.camera_ids.size() - 1);
  const std::uint8_t shape = in.ConsumeIntegral<std::uint8_t>();
  o.camera_id = (shape & 0x01) ? in.ConsumeIntegral<std::uint8_t>()
                               : static_cast<std::uint8_t>(c.camera_ids[cam]);
  o.unit_id =
      (shape & 0x02) ? in.ConsumeIntegral<std::uint8_t>() : static_cast<std::uint8_t>(cam / 2);
  const std::uint32_t seq = in.ConsumeIntegralInRange<std::uint32_t>(0, 4000);
  o.trigger_seq = (shape & 0x04) ? in.ConsumeIntegral<std::uint32_t>() : seq;
  const std::int64_t jitter = in.ConsumeIntegralInRange<std::int64_t>(-5'000'000, 5'000'000);
  const std::int64_t on_grid_tai_ns = kStartTaiNs + kPeriodNs * seq + jitter;
  o.exposure_start_tai_ns = (shape & 0x08) ? in.ConsumeIntegral<std::int64_t>() : on_grid_tai_ns;
  o.exposure_start_mono_ns = (shape & 0x10) ? in.ConsumeIntegral<std::int64_t>()
                                            : on_grid_tai_ns - kStartTaiNs + 1'000'000;
  o.exposure_duration_ns = (shape & 0x20) ? in.ConsumeIntegral<std::uint32_t>() : 500'000;
  o.clock_state = 2;
  o.mark_count = (shape & 0x40) ? in.ConsumeIntegral<std::uint8_t>() : 4;
  o.marks[kTagMark].x_px = static_cast<float>(serial);  // exact below 2^24
  return o;
}

// STORETRACK_FUZZ_TRACE=1: print the pushes and releases (to read a crash's input).
const bool kTrace = std::getenv("STORETRACK_FUZZ_TRACE") != nullptr;

void trace_push(const msg::MarkObservations& o, std::int64_t now) {
  if (!kTrace) return;
  std::fprintf(stderr, "push now=%lld cam=%d unit=%d seq=%u tai=%lld mono=%lld dur=%u marks=%d\n",
               static_cast<long long>(now), o.camera_id, o.unit_id, o.trigger_seq,
               static_cast<long long>(o.exposure_start_tai_ns),
               static_cast<long long>(o.exposure_start_mono_ns), o.exposure_duration_ns,
               o.mark_count);
}

void trace_release(const AlignedExposure& e) {
  if (!kTrace) return;
  std::fprintf(stderr, "release seq=%u mid=%lld missing=%x timeout=%d cams:", e.trigger_seq,
               static_cast<long long>(e.exposure_mid_tai_ns), e.missing_camera_mask,
               e.closed_by_timeout);
  for (const auto& o : e.cameras)
    std::fprintf(stderr, " %d/%u", o.camera_id, o.trigger_seq);
  std::fprintf(stderr, "\n");
}

struct Audit {
  std::set<std::uint32_t> serials;
  std::set<std::tuple<int, std::uint32_t, std::int64_t>> used;
  std::uint64_t cameras_released = 0;
};

void check_released(const AlignedExposure& e, const ingest::AlignerConfig& c, Audit& audit) {
  trace_release(e);
  if (e.cameras.size() < static_cast<std::size_t>(c.min_cameras)) std::abort();
  if (e.exposure_mid_tai_ns == std::numeric_limits<std::int64_t>::min()) std::abort();
  std::uint32_t present = 0;
  for (const auto& o : e.cameras) {
    std::size_t i = 0;
    while (i < c.camera_ids.size() && c.camera_ids[i] != o.camera_id)
      ++i;
    if (i == c.camera_ids.size() || (present >> i & 1u)) std::abort();  // foreign or twice
    present |= 1u << i;
    if (!audit.serials.insert(static_cast<std::uint32_t>(o.marks[kTagMark].x_px)).second)
      std::abort();  // this observation was released before
    if (!audit.used.insert({o.camera_id, o.trigger_seq, o.exposure_start_tai_ns}).second)
      std::abort();  // this camera's exposure was released before
  }
  const std::uint32_t all = (1u << c.camera_ids.size()) - 1;
  if (e.missing_camera_mask != (all & ~present)) std::abort();
  audit.cameras_released += e.cameras.size();
}

std::uint64_t dropped_total(const ingest::AlignerCounters& k) {
  return k.dropped_unknown_camera + k.dropped_spoofed + k.dropped_invalid +
         k.dropped_time_out_of_range + k.dropped_duplicate + k.dropped_late +
         k.dropped_time_mismatch + k.dropped_quarantined + k.dropped_too_few_cameras +
         k.dropped_numbering_unknown;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  FuzzedDataProvider in(data, size);
  const ingest::AlignerConfig config = make_config(in);
  ingest::ExposureAligner aligner(config);
  if (kTrace)
    std::fprintf(stderr,
                 "config cameras=%zu units=%zu wait=%lld spread=%lld pending=%zu min=%d lead=%u\n",
                 config.camera_ids.size(), config.unit_ids.size(),
                 static_cast<long long>(config.max_wait_ns),
                 static_cast<long long>(config.max_mid_time_spread_ns), config.max_pending,
                 config.min_cameras, config.max_sequence_lead);
  std::vector<AlignedExposure> out;
  Audit audit;
  std::int64_t now = 1'000'000'000;
  std::uint32_t serial = 0;
  while (in.remaining_bytes() > 0 && serial < 4096) {
    now += in.ConsumeIntegralInRange<std::int64_t>(0, 20'000'000);
    if (in.ConsumeBool()) {
      const msg::MarkObservations o = make_observation(in, config, serial++);
      trace_push(o, now);
      aligner.push(o, now, out);
    } else {
      aligner.poll(now, out);
      if (aligner.next_deadline() <= now) std::abort();  // an overdue exposure was kept
    }
    if (aligner.pending() > config.max_pending || aligner.held() > config.camera_ids.size())
      std::abort();
    for (const auto& e : out)
      check_released(e, config, audit);
    out.clear();
  }
  aligner.flush(out);
  for (const auto& e : out)
    check_released(e, config, audit);
  const auto& k = aligner.counters();
  if (aligner.pending() != 0 || aligner.held() != 0) std::abort();
  if (k.observations_in != serial) std::abort();
  if (k.observations_in != k.observations_used + dropped_total(k)) std::abort();
  if (audit.cameras_released != k.observations_used) std::abort();
  return 0;
}
