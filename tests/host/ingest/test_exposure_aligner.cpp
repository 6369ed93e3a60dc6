// ExposureAligner under injected faults: loss, duplicates, reordering, a dead camera, clock
// jumps, sequence wrap and restart, overflow. Every test checks the released exposures against
// what was injected (the truth), and that every dropped observation is counted with its reason.
#include "aligner_test_support.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"
#include "storetrack/time/saturating.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <random>
#include <set>

namespace storetrack::ingest {
namespace {

using test::kPeriodNs;
using test::kT0Tai;
using test::total_dropped;

msg::MarkObservations make_obs(int camera_id, std::uint32_t seq, std::int64_t start_tai) {
  return test::make_observation(camera_id / 2, camera_id, seq, start_tai);
}

AlignerConfig config4() {
  AlignerConfig c;
  c.camera_ids = {10, 11, 12, 13};
  c.max_wait_ns = 10'000'000;
  return c;
}

TEST(ExposureAligner, ReleasedExposureCarriesItsLastArrivalTime) {
  // The host's latency starts at the exposure's last observation in. It was looked up by the
  // camera's trigger_seq in a map of the host loop: wrong for a camera whose numbering has an
  // offset (a restarted unit), and never erased for observations the aligner dropped.
  ExposureAligner aligner(config4());
  std::vector<pipeline::AlignedExposure> out;
  const std::int64_t arrivals[4] = {1'000, 4'000, 2'500, 3'000};
  for (int c = 0; c < 4; ++c)
    aligner.push(make_obs(10 + c, 7, kT0Tai + c * 1000), arrivals[c], out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].last_arrival_mono_ns, 4'000);
}

TEST(ExposureAligner, CompleteExposuresReleaseImmediatelyInOrder) {
  ExposureAligner aligner(config4());
  std::vector<pipeline::AlignedExposure> out;
  for (std::uint32_t k = 0; k < 100; ++k) {
    const std::int64_t now = static_cast<std::int64_t>(k) * kPeriodNs;
    for (int c = 0; c < 4; ++c) {
      const std::size_t before = out.size();
      aligner.push(make_obs(10 + c, 1000 + k, kT0Tai + now + c * 1000), now + c * 10'000, out);
      // Released exactly when the last camera arrives, not one observation earlier.
      EXPECT_EQ(out.size(), before + (c == 3 ? 1 : 0));
    }
  }
  ASSERT_EQ(out.size(), 100u);
  for (std::uint32_t k = 0; k < 100; ++k) {
    EXPECT_EQ(out[k].trigger_seq, 1000 + k);
    EXPECT_EQ(out[k].cameras.size(), 4u);
    EXPECT_EQ(out[k].missing_camera_mask, 0u);
    EXPECT_FALSE(out[k].closed_by_timeout);
    // Mid-point of the earliest-starting camera (camera 10 starts first).
    EXPECT_EQ(out[k].exposure_mid_tai_ns, kT0Tai + k * kPeriodNs + 250'000);
  }
  EXPECT_EQ(aligner.counters().exposures_complete, 100u);
  EXPECT_EQ(total_dropped(aligner.counters()), 0u);
  EXPECT_EQ(aligner.pending(), 0u);
}

TEST(ExposureAligner, DeadCameraNeverStallsOutputBeyondTheWait) {
  AlignerConfig cfg = config4();
  ExposureAligner aligner(cfg);
  std::vector<pipeline::AlignedExposure> out;
  std::int64_t worst_delay = 0;
  std::map<std::uint32_t, std::int64_t> first_arrival;
  for (std::uint32_t k = 0; k < 200; ++k) {
    const std::int64_t now = static_cast<std::int64_t>(k) * kPeriodNs;
    const std::size_t before = out.size();
    aligner.poll(now, out);
    for (int c = 0; c < 4; ++c) {
      if (c == 2) continue;  // camera 12 is dead
      aligner.push(make_obs(10 + c, k, kT0Tai + now), now, out);
    }
    first_arrival[k] = now;
    for (std::size_t i = before; i < out.size(); ++i)
      worst_delay = std::max(worst_delay, now - first_arrival[out[i].trigger_seq]);
  }
  aligner.flush(out);
  ASSERT_EQ(out.size(), 200u);
  for (std::uint32_t k = 0; k < 200; ++k) {
    EXPECT_EQ(out[k].trigger_seq, k);
    EXPECT_EQ(out[k].missing_camera_mask, 1u << 2);
    EXPECT_EQ(out[k].cameras.size(), 3u);
    EXPECT_TRUE(out[k].closed_by_timeout);
  }
  // Polled once per exposure period: release within the wait plus one period.
  EXPECT_LE(worst_delay, cfg.max_wait_ns + kPeriodNs);
  EXPECT_EQ(aligner.counters().exposures_partial_timeout, 200u);
  EXPECT_EQ(aligner.camera_counters()[2].missing, 200u);
  EXPECT_EQ(aligner.camera_counters()[0].missing, 0u);
}

TEST(ExposureAligner, LossDuplicatesAndReorderingAreToleratedAndCounted) {
  std::mt19937_64 rng(42);
  AlignerConfig cfg = config4();
  cfg.max_wait_ns = 20'000'000;
  ExposureAligner aligner(cfg);
  struct Arrival {
    std::int64_t t;
    msg::MarkObservations obs;
  };
  std::vector<Arrival> arrivals;
  std::map<std::uint32_t, std::set<int>> delivered;  // truth: what reached the host
  std::uniform_real_distribution<double> u01(0, 1);
  std::normal_distribution<double> jitter(0, 1.5e6);  // 1.5 ms of network jitter: reorders
  int injected_duplicates = 0;
  const std::uint32_t n = 2000;
  for (std::uint32_t k = 0; k < n; ++k) {
    const std::int64_t t = static_cast<std::int64_t>(k) * kPeriodNs;
    for (int c = 0; c < 4; ++c) {
      if (u01(rng) < 0.10) continue;  // lost
      const auto obs = make_obs(10 + c, k, kT0Tai + t);
      const std::int64_t arrive = t + std::abs(static_cast<std::int64_t>(jitter(rng)));
      arrivals.push_back({arrive, obs});
      delivered[k].insert(c);
      if (u01(rng) < 0.05) {  // duplicated shortly after
        arrivals.push_back({arrive + 200'000, obs});
        ++injected_duplicates;
      }
    }
  }
  std::stable_sort(arrivals.begin(), arrivals.end(),
                   [](const Arrival& a, const Arrival& b) { return a.t < b.t; });
  std::vector<pipeline::AlignedExposure> out;
  for (const auto& a : arrivals) {
    aligner.poll(a.t, out);
    aligner.push(a.obs, a.t, out);
  }
  aligner.flush(out);

  // Released strictly in order, each once, each camera at most once, nothing invented.
  std::set<std::uint32_t> released;
  std::uint32_t previous = 0;
  std::uint64_t used = 0;
  for (std::size_t i = 0; i < out.size(); ++i) {
    const auto& e = out[i];
    if (i > 0) {
      EXPECT_GT(e.trigger_seq, previous);
    }
    previous = e.trigger_seq;
    EXPECT_TRUE(released.insert(e.trigger_seq).second);
    std::set<int> cams;
    for (const auto& o : e.cameras) {
      EXPECT_EQ(o.trigger_seq, e.trigger_seq);
      EXPECT_TRUE(cams.insert(o.camera_id - 10).second) << "camera twice in one exposure";
      EXPECT_TRUE(delivered[e.trigger_seq].count(o.camera_id - 10));
      EXPECT_EQ(e.missing_camera_mask & (1u << (o.camera_id - 10)), 0u);
    }
    used += e.cameras.size();
  }
  // Every exposure that reached the host with a camera is released (jitter < wait).
  for (const auto& [k, cams] : delivered) {
    EXPECT_TRUE(released.count(k)) << k;
  }
  const auto& c = aligner.counters();
  EXPECT_EQ(c.observations_in, arrivals.size());
  EXPECT_EQ(c.observations_in, c.observations_used + total_dropped(c));
  EXPECT_EQ(c.observations_used, used);
  EXPECT_EQ(c.dropped_duplicate + c.dropped_late, static_cast<std::uint64_t>(injected_duplicates));
  EXPECT_GT(c.exposures_partial_timeout, 0u);
  EXPECT_EQ(c.dropped_time_mismatch, 0u);
}

TEST(ExposureAligner, UnitClockJumpDropsOnlyTheJumpedCamera) {
  ExposureAligner aligner(config4());
  std::vector<pipeline::AlignedExposure> out;
  int jumped = 0;
  for (std::uint32_t k = 0; k < 100; ++k) {
    const std::int64_t now = static_cast<std::int64_t>(k) * kPeriodNs;
    aligner.poll(now, out);
    for (int c = 0; c < 4; ++c) {
      std::int64_t tai = kT0Tai + now;
      if (c == 1 && k >= 50) {
        tai += 1'000'000'000;  // camera 11's unit clock stepped by 1 s
        ++jumped;
      }
      aligner.push(make_obs(10 + c, k, tai), now, out);
    }
  }
  aligner.flush(out);
  ASSERT_EQ(out.size(), 100u);
  for (std::uint32_t k = 0; k < 100; ++k)
    EXPECT_EQ(out[k].missing_camera_mask, k >= 50 ? 1u << 1 : 0u) << k;
  EXPECT_EQ(aligner.counters().dropped_time_mismatch, static_cast<std::uint64_t>(jumped));
  EXPECT_EQ(aligner.camera_counters()[1].time_mismatch, static_cast<std::uint64_t>(jumped));
}

TEST(ExposureAligner, SequenceWrapAndRestart) {
  ExposureAligner aligner(config4());
  std::vector<pipeline::AlignedExposure> out;
  std::vector<std::uint32_t> sent;
  std::int64_t now = 0;
  auto send_exposure = [&](std::uint32_t seq) {
    for (int c = 0; c < 4; ++c)
      aligner.push(make_obs(10 + c, seq, kT0Tai + now), now, out);
    sent.push_back(seq);
    now += kPeriodNs;
  };
  for (std::uint32_t k = 0; k < 20; ++k) {
    // Wraps past 2^32; 0xFFFFFFFF is the schema's "invalid" value, which units never send.
    if (0xFFFFFFF0u + k != 0xFFFFFFFFu) send_exposure(0xFFFFFFF0u + k);
  }
  for (std::uint32_t k = 4; k < 2004; ++k)
    send_exposure(k);  // continues
  for (std::uint32_t k = 0; k < 20; ++k)
    send_exposure(k);  // trigger restarted
  ASSERT_EQ(out.size(), sent.size());
  for (std::size_t i = 0; i < sent.size(); ++i)
    EXPECT_EQ(out[i].trigger_seq, sent[i]);
  // 0xFFFFFFF0 -> 3 is a wrap, and skipping 0xFFFFFFFF one period later leaves the sequence a
  // step ahead of the trigger grid; 2003 -> 0 is far behind: a restart on the same grid. Each is
  // a re-learned offset of every camera (4 + 4), losing nothing.
  EXPECT_EQ(aligner.counters().sequence_offset_changes, 8u);
  EXPECT_EQ(total_dropped(aligner.counters()), 0u);
}

TEST(ExposureAligner, LateObservationAfterReleaseIsCountedNotReleasedTwice) {
  ExposureAligner aligner(config4());
  std::vector<pipeline::AlignedExposure> out;
  for (int c = 0; c < 3; ++c)
    aligner.push(make_obs(10 + c, 7, kT0Tai), 0, out);
  aligner.poll(20'000'000, out);  // deadline passed: released without camera 13
  ASSERT_EQ(out.size(), 1u);
  aligner.push(make_obs(13, 7, kT0Tai), 21'000'000, out);  // straggler
  aligner.push(make_obs(10, 7, kT0Tai), 21'000'000, out);  // duplicate of a released one
  EXPECT_EQ(out.size(), 1u);
  EXPECT_EQ(aligner.counters().dropped_late, 1u);
  EXPECT_EQ(aligner.counters().dropped_duplicate, 1u);
  EXPECT_EQ(aligner.pending(), 0u);
}

TEST(ExposureAligner, BoundedPendingAndBadInputAreCounted) {
  AlignerConfig cfg = config4();
  cfg.max_pending = 8;
  ExposureAligner aligner(cfg);
  std::vector<pipeline::AlignedExposure> out;
  for (std::uint32_t k = 0; k < 50; ++k)
    aligner.push(make_obs(10, k, kT0Tai + k * kPeriodNs), 0, out);
  EXPECT_LE(aligner.pending(), 8u);
  EXPECT_EQ(aligner.counters().exposures_partial_overflow, 42u);
  aligner.push(make_obs(99, 60, kT0Tai), 0, out);
  auto bad = make_obs(11, 0xFFFFFFFFu, kT0Tai);
  aligner.push(bad, 0, out);
  bad = make_obs(11, 61, INT64_MIN);
  aligner.push(bad, 0, out);
  EXPECT_EQ(aligner.counters().dropped_unknown_camera, 1u);
  EXPECT_EQ(aligner.counters().dropped_invalid, 2u);
}

TEST(ExposureAligner, MinCamerasDropsUnderdeliveredExposures) {
  AlignerConfig cfg = config4();
  cfg.min_cameras = 2;
  ExposureAligner aligner(cfg);
  std::vector<pipeline::AlignedExposure> out;
  aligner.push(make_obs(10, 1, kT0Tai), 0, out);
  aligner.poll(cfg.max_wait_ns, out);
  EXPECT_TRUE(out.empty());
  EXPECT_EQ(aligner.counters().exposures_dropped_too_few_cameras, 1u);
  EXPECT_EQ(aligner.next_deadline(), INT64_MAX);
}

}  // namespace
}  // namespace storetrack::ingest
