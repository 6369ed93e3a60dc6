// The contract storetrack-post's bit-identical replay rests on (docs/post-processing.md): the
// aligner is a function of its calls, and a poll() that returns false left it as it was. A
// host-like loop (pushes at the loop's time, a poll every 0.1-1.5 ms) over a rig with loss, late
// arrivals, a camera that dies, lone jumped sequences and a stall is the truth; a second aligner
// given only its pushes, the polls that returned true and the flush must release the same
// exposures, each the same, and count the same.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <vector>

#include "aligner_test_support.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"

namespace storetrack::ingest {
namespace {

using test::kPeriodNs;
using test::kT0Tai;

AlignerConfig rig_config() {
  AlignerConfig c;
  c.camera_ids = {10, 11, 12, 13};
  c.unit_ids = {0, 0, 1, 1};
  c.max_wait_ns = 10'000'000;
  return c;
}

struct Arrival {
  std::int64_t at_ns;
  msg::MarkObservations obs;
};

// What the cameras send and when it reaches the host: 600 exposures at 400 fps, 0.1-6 ms link
// latency (5 % of them 12-25 ms: later than the wait), 15 % loss, camera 13 dead after exposure
// 400, a lone camera 10 observation with its sequence 100 000 ahead every 37th exposure, bursts and
// a stall.
std::vector<Arrival> arrivals(std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<std::int64_t> latency(100'000, 6'000'000);
  std::uniform_int_distribution<std::int64_t> late_latency(12'000'000, 25'000'000);
  std::bernoulli_distribution lost(0.15), late(0.05);
  std::vector<Arrival> out;
  for (int k = 0; k < 600; ++k) {
    // Bursts of 25 exposures 30 ms apart (longer than the wait: each burst's last partial
    // exposures go on a deadline, not pushed out by the next one), one 200 ms stall.
    const std::int64_t t = static_cast<std::int64_t>(k) * kPeriodNs + (k / 25) * 30'000'000 +
                           (k >= 300 ? 200'000'000 : 0);
    const auto seq = static_cast<std::uint32_t>(1000 + k);
    for (int c = 0; c < 4; ++c) {
      if (lost(rng) || (c == 3 && k > 400)) continue;
      const std::int64_t delay = late(rng) ? late_latency(rng) : latency(rng);
      out.push_back({t + delay, test::make_observation(c / 2, 10 + c, seq, kT0Tai + t)});
    }
    if (k % 37 == 5)
      out.push_back({t + latency(rng), test::make_observation(0, 10, seq + 100'000, kT0Tai + t)});
  }
  std::stable_sort(out.begin(), out.end(),
                   [](const Arrival& a, const Arrival& b) { return a.at_ns < b.at_ns; });
  return out;
}

// One call the live loop made that a recording keeps: a push, a poll that changed something, or
// the flush.
struct Call {
  enum Kind { kPush, kPoll, kFlush } kind;
  std::int64_t now;
  msg::MarkObservations obs{};
};

struct Live {
  std::vector<pipeline::AlignedExposure> released;
  std::vector<Call> recorded;
  AlignerCounters counters;
  int polls_unchanged = 0, polls_changed = 0;
};

Live run_live(const std::vector<Arrival>& in, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<std::int64_t> step(100'000, 1'500'000);
  ExposureAligner aligner(rig_config());
  Live live;
  std::int64_t now = 0;
  std::size_t next = 0;
  while (next < in.size() || now < in.back().at_ns + 100'000'000) {
    now += step(rng);
    for (; next < in.size() && in[next].at_ns <= now; ++next) {
      live.recorded.push_back({Call::kPush, now, in[next].obs});
      aligner.push(in[next].obs, now, live.released);
    }
    if (aligner.poll(now, live.released)) {
      live.recorded.push_back({Call::kPoll, now});
      ++live.polls_changed;
    } else {
      ++live.polls_unchanged;
    }
  }
  aligner.flush(live.released);
  live.recorded.push_back({Call::kFlush, now});
  live.counters = aligner.counters();
  return live;
}

std::vector<pipeline::AlignedExposure> replay(const std::vector<Call>& calls,
                                              AlignerCounters& counters) {
  ExposureAligner aligner(rig_config());
  std::vector<pipeline::AlignedExposure> out;
  for (const Call& c : calls) {
    if (c.kind == Call::kPush) aligner.push(c.obs, c.now, out);
    if (c.kind == Call::kPoll) aligner.poll(c.now, out);
    if (c.kind == Call::kFlush) aligner.flush(out);
  }
  counters = aligner.counters();
  return out;
}

void expect_same_exposure(const pipeline::AlignedExposure& a, const pipeline::AlignedExposure& b,
                          std::size_t i) {
  EXPECT_EQ(a.trigger_seq, b.trigger_seq) << i;
  EXPECT_EQ(a.missing_camera_mask, b.missing_camera_mask) << i;
  EXPECT_EQ(a.exposure_mid_tai_ns, b.exposure_mid_tai_ns) << i;
  EXPECT_EQ(a.closed_by_timeout, b.closed_by_timeout) << i;
  EXPECT_EQ(a.last_arrival_mono_ns, b.last_arrival_mono_ns) << i;
  ASSERT_EQ(a.cameras.size(), b.cameras.size()) << i;
  for (std::size_t c = 0; c < a.cameras.size(); ++c) {
    EXPECT_EQ(a.cameras[c].camera_id, b.cameras[c].camera_id) << i;
    EXPECT_EQ(a.cameras[c].trigger_seq, b.cameras[c].trigger_seq) << i;
  }
}

void expect_same_counters(const AlignerCounters& a, const AlignerCounters& b) {
  EXPECT_EQ(a.observations_in, b.observations_in);
  EXPECT_EQ(a.observations_used, b.observations_used);
  EXPECT_EQ(a.exposures_complete, b.exposures_complete);
  EXPECT_EQ(a.exposures_partial_timeout, b.exposures_partial_timeout);
  EXPECT_EQ(a.exposures_partial_overflow, b.exposures_partial_overflow);
  EXPECT_EQ(test::total_dropped(a), test::total_dropped(b));
  EXPECT_EQ(a.dropped_quarantined, b.dropped_quarantined);
  EXPECT_EQ(a.dropped_late, b.dropped_late);
  EXPECT_EQ(a.camera_missing_total, b.camera_missing_total);
}

TEST(ExposureAlignerReplay, OnlyThePollsThatChangedSomethingAreNeeded) {
  for (const std::uint64_t seed : {1u, 2u, 3u}) {
    SCOPED_TRACE(seed);
    const Live live = run_live(arrivals(seed), seed);
    // The case exercises what the contract is about: deadlines that release, polls that do not.
    EXPECT_GT(live.counters.exposures_partial_timeout, 10u);
    EXPECT_GT(live.counters.dropped_late, 0u);
    EXPECT_GT(live.polls_changed, 10);
    EXPECT_GT(live.polls_unchanged, 10 * live.polls_changed);
    AlignerCounters counters;
    const auto again = replay(live.recorded, counters);
    ASSERT_EQ(again.size(), live.released.size());
    for (std::size_t i = 0; i < again.size(); ++i)
      expect_same_exposure(again[i], live.released[i], i);
    expect_same_counters(counters, live.counters);
  }
}

// The deadline events are needed: without them an observation that came after its exposure's
// deadline (dropped late, live) finds the exposure still pending at the end of a burst.
TEST(ExposureAlignerReplay, WithoutTheDeadlineEventsTheReleasesDiffer) {
  const Live live = run_live(arrivals(1), 1);
  std::vector<Call> pushes_only;
  for (const Call& c : live.recorded)
    if (c.kind != Call::kPoll) pushes_only.push_back(c);
  AlignerCounters counters;
  const auto again = replay(pushes_only, counters);
  bool differs = again.size() != live.released.size();
  for (std::size_t i = 0; !differs && i < again.size(); ++i)
    differs = again[i].trigger_seq != live.released[i].trigger_seq ||
              again[i].missing_camera_mask != live.released[i].missing_camera_mask ||
              again[i].closed_by_timeout != live.released[i].closed_by_timeout;
  EXPECT_TRUE(differs);
  EXPECT_NE(counters.dropped_late, live.counters.dropped_late);
}

}  // namespace
}  // namespace storetrack::ingest
