// ExposureAligner against one forged datagram (issue 31): a valid-looking observation of a real
// unit and camera, its time consistent with a future trigger edge, numbered 3, 50, 600 or 2000
// exposures ahead, with the production wait (10 ms) and with tools/testpoint's (5 s), delivered
// in real time (2.5 ms per exposure) and in the main job's slow motion (the units render about
// 20 exposures/s of host time: 50 ms per exposure). Before, with the 5 s wait the lead window was
// 5 s / 2.5 ms = 2000 exposures: the forged exposure opened alone and, at its timeout, forced
// every exposure pending before it out as partial. The truth is what each camera exposed.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "aligner_test_support.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"

namespace storetrack::ingest {
namespace {

constexpr std::uint32_t kSeq0 = 7000;
constexpr int kCameras = 4;
constexpr int kExposures = 220;  // the main job's store_separation run
constexpr int kForgedCamera = 11;
constexpr float kForgedX = 999.0F;  // marks the forged observation in the output

using test::kPeriodNs;
using test::kT0Tai;

struct ForgedCase {
  std::int64_t max_wait_ns = 0;
  std::int64_t delivery_ns = 0;  // host time between two exposures' deliveries
  int lead = 0;                  // exposures ahead of the rig's current one
  int at = 50;                   // injected just before this exposure's observations
  std::string name() const {
    return "wait " + std::to_string(max_wait_ns / 1'000'000) + " ms, delivery " +
           std::to_string(delivery_ns / 1000) + " us, lead " + std::to_string(lead) + " at " +
           std::to_string(at);
  }
};

msg::MarkObservations observation(int camera, int k) {
  return test::make_observation((camera - 10) / 2, camera, kSeq0 + static_cast<std::uint32_t>(k),
                                kT0Tai + k * kPeriodNs);
}

struct Outcome {
  std::vector<pipeline::AlignedExposure> out;
  AlignerCounters counters;
};

Outcome run(const ForgedCase& fc) {
  AlignerConfig c;
  for (int i = 0; i < kCameras; ++i) {
    c.camera_ids.push_back(10 + i);
    c.unit_ids.push_back(i / 2);
  }
  c.max_wait_ns = fc.max_wait_ns;
  c.max_pending = 4096;  // tools/testpoint: the whole run may be pending
  ExposureAligner aligner(c);
  Outcome r;
  const auto inject = [&](int k, std::int64_t now) {
    msg::MarkObservations forged = observation(kForgedCamera, k + fc.lead);
    forged.marks[0].x_px = kForgedX;
    aligner.push(forged, now, r.out);
  };
  for (int k = 0; k <= kExposures; ++k) {
    const std::int64_t now = 1'000'000'000 + k * fc.delivery_ns;
    aligner.poll(now, r.out);
    // Nothing overdue is kept (the host loop sleeps until next_deadline()).
    EXPECT_GT(aligner.next_deadline(), now);
    if (k == fc.at) inject(k, now);
    if (k == kExposures) break;  // after the last exposure: only the flush can take it back
    for (int cam = 0; cam < kCameras; ++cam)
      aligner.push(observation(10 + cam, k), now + 20'000 * (cam + 1), r.out);
  }
  aligner.flush(r.out);
  r.counters = aligner.counters();
  return r;
}

// Exposures the forged datagram cost: not released complete with every camera's true
// observation under its own sequence, or released with the forged one.
int exposures_lost(const Outcome& r) {
  int good = 0;
  for (const auto& e : r.out) {
    bool forged = false;
    for (const auto& o : e.cameras)
      forged = forged || o.marks[0].x_px == kForgedX;
    const int k = static_cast<int>(e.trigger_seq - kSeq0);
    if (!forged && e.missing_camera_mask == 0 && k >= 0 && k < kExposures) ++good;
  }
  return kExposures - good;
}

void expect_bounded_cost(const ForgedCase& fc) {
  SCOPED_TRACE(fc.name());
  const Outcome r = run(fc);
  const AlignerCounters& c = r.counters;
  if (fc.lead <= 4) {
    // Within the lead window (4 exposures at 400 fps) a forged datagram is indistinguishable
    // from its camera running ahead: it takes the place of that camera's true observation of
    // one exposure (the true one is a duplicate). When the others come later than the wait
    // (slow motion with the 10 ms wait: 50 ms apart) that exposure goes alone at its wait and
    // the others' observations of it and of the exposures before it are late: at most `lead`.
    const bool slow = fc.delivery_ns > fc.max_wait_ns;
    EXPECT_LE(exposures_lost(r), slow ? fc.lead : 1);
    EXPECT_LE(c.dropped_late, static_cast<std::uint64_t>(slow ? kCameras * fc.lead : 0));
    EXPECT_LE(c.exposures_partial_timeout + c.exposures_partial_overflow, 1u);
    EXPECT_EQ(c.dropped_duplicate, 1u);
  } else {
    // Further ahead it is quarantined, or opens an exposure no other camera confirms that is
    // taken back: never released, it costs nothing.
    EXPECT_EQ(exposures_lost(r), 0);
    for (const auto& e : r.out) {
      EXPECT_EQ(e.cameras.size(), static_cast<std::size_t>(kCameras));
      EXPECT_LT(static_cast<int>(e.trigger_seq - kSeq0), kExposures) << "the forged exposure";
    }
    EXPECT_EQ(c.dropped_late, 0u) << "the forged exposure forced the others out";
    EXPECT_EQ(c.exposures_partial_timeout + c.exposures_partial_overflow, 0u);
    EXPECT_EQ(c.dropped_quarantined, 1u);
    EXPECT_EQ(c.dropped_duplicate, 0u);
  }
  EXPECT_EQ(c.sequence_offset_changes + c.sequence_restarts, 0u);
  test::expect_every_observation_accounted(c);
}

constexpr std::int64_t kProductionWaitNs = 10'000'000;
constexpr std::int64_t kTestpointWaitNs = 5 * time::kNsPerSecond;
constexpr std::int64_t kRealTimeNs = kPeriodNs;
constexpr std::int64_t kSlowMotionNs = 50'000'000;

TEST(ExposureAlignerForged, ForgedLeadWithTheProductionWaitIsQuarantined) {
  for (const int lead : {3, 50, 600, 2000})
    for (const std::int64_t delivery : {kRealTimeNs, kSlowMotionNs})
      expect_bounded_cost({kProductionWaitNs, delivery, lead});
}

TEST(ExposureAlignerForged, ForgedLeadWithTheTestpointWaitIsQuarantined) {
  // The lead window does not grow with the wait: the 5 s wait behaves as the 10 ms one.
  for (const int lead : {3, 50, 600, 2000})
    for (const std::int64_t delivery : {kRealTimeNs, kSlowMotionNs})
      expect_bounded_cost({kTestpointWaitNs, delivery, lead});
}

TEST(ExposureAlignerForged, ForgedLeadAtTheEndOfTheRunIsNeverReleased) {
  // Injected after the last exposure: no later observation takes it back; its wait or the flush
  // does (in slow motion its arrival time looks like a gap's: it opened an exposure nobody
  // confirmed). (Inside the window, 3 ahead, it is a camera ahead of the others: its exposure
  // goes partial at its wait, like a survivor's when the other cameras died.)
  for (const std::int64_t wait : {kProductionWaitNs, kTestpointWaitNs})
    for (const std::int64_t delivery : {kRealTimeNs, kSlowMotionNs})
      for (const int lead : {50, 600, 2000})
        expect_bounded_cost({wait, delivery, lead, kExposures});
}

TEST(ExposureAlignerForged, CameraRunningAheadInSlowMotionIsNotTakenForAForgery) {
  // Camera 13 runs ahead of the others, up to 2 s of host time and 48 exposures at the end, in
  // slow motion (its unit renders faster), with the 5 s wait: its own stream vouches for each
  // step, so its lone exposures are opened and wait for the others; none is taken back.
  AlignerConfig c;
  for (int i = 0; i < kCameras; ++i)
    c.camera_ids.push_back(10 + i);
  c.max_wait_ns = kTestpointWaitNs;
  c.max_pending = 4096;
  ExposureAligner aligner(c);
  std::vector<pipeline::AlignedExposure> out;
  std::vector<std::pair<std::int64_t, msg::MarkObservations>> arrivals;
  for (int k = 0; k < kExposures; ++k) {
    for (int cam = 0; cam < 3; ++cam)
      arrivals.emplace_back(1'000'000'000 + k * kSlowMotionNs + cam * 1000,
                            observation(10 + cam, k));
    arrivals.emplace_back(1'000'000'000 + k * (kSlowMotionNs - 9'000'000), observation(13, k));
  }
  std::stable_sort(arrivals.begin(), arrivals.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  for (const auto& [now, o] : arrivals) {
    aligner.poll(now, out);
    EXPECT_GT(aligner.next_deadline(), now) << "an overdue exposure was kept";
    aligner.push(o, now, out);
  }
  aligner.flush(out);
  ASSERT_EQ(out.size(), static_cast<std::size_t>(kExposures));
  for (const auto& e : out)
    EXPECT_EQ(e.missing_camera_mask, 0u) << e.trigger_seq - kSeq0;
  EXPECT_EQ(aligner.counters().dropped_quarantined, 0u);
  EXPECT_EQ(aligner.counters().dropped_late, 0u);
  test::expect_every_observation_accounted(aligner.counters());
}

}  // namespace
}  // namespace storetrack::ingest
