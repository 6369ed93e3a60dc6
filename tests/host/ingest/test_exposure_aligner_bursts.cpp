// ExposureAligner under the burst losses and host stalls of a loaded host (issue 11, soak
// finding): 4 units x 2 cameras at 400 fps whose trigger sequences, TAI and monotonic times are
// all consistent, nothing restarted or duplicated. Bursts of lost datagrams (one unit's or every
// unit's) and host stalls (no reads for 50-250 ms, then the socket's backlog read in arrival
// order, 256 per call as UdpReceiver does, the tail dropped when the socket buffer is full) must
// not look like restarts, offset changes, duplicates or clock faults. The truth is the stream:
// which camera's datagram of which exposure reached the aligner.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <deque>
#include <limits>
#include <map>
#include <string>
#include <vector>

#include "aligner_test_support.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"

namespace storetrack::ingest {
namespace {

using test::kPeriodNs;
using test::kT0Tai;
using test::total_dropped;

constexpr int kUnits = 4;
constexpr int kCameras = 2 * kUnits;
constexpr std::uint32_t kSeq0 = 5000;            // the trigger sequence of exposure 0
constexpr std::int64_t kHostT0 = 1'000'000'000;  // host CLOCK_MONOTONIC at exposure 0's start
constexpr std::size_t kReadsPerCall = 256;       // UdpReceiver::kMaxDatagramsPerReceive
constexpr std::int64_t kProcessingNs = 300'000;  // host time per released exposure

// Deterministic pseudo-random in [0, 1) from (camera, exposure): the units' latency jitter.
double hash01(int camera, int k) {
  std::uint64_t z = static_cast<std::uint64_t>(k) * 0x9E3779B97F4A7C15ull +
                    static_cast<std::uint64_t>(camera) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return static_cast<double>((z ^ (z >> 31)) >> 11) * 0x1.0p-53;
}

struct LossBurst {
  int unit = -1;  // -1: every unit at once
  int first = 0;  // first exposure lost
  int count = 0;
};
struct Stall {
  std::int64_t at_ns = 0;  // host time (since exposure 0) at which the host stops reading
  std::int64_t for_ns = 0;
};
struct BurstCase {
  std::string name;
  int exposures = 3000;
  std::vector<LossBurst> losses;
  std::vector<Stall> stalls;
  std::size_t socket_capacity = 1'000'000;  // datagrams; beyond it the kernel drops
};

struct Datagram {
  std::int64_t arrival = 0;  // host time it reaches the socket
  int camera = 0;
  int k = 0;
};

// Arrival at the socket: after the exposure's end, 0.8 ms + 0.5 ms per unit + the camera's 30 us
// + up to 1.5 ms of jitter (0.8-3.8 ms, more than a period): units and cameras interleave, and
// the next exposure's first datagrams come before this one's last.
std::vector<Datagram> stream(const BurstCase& bc) {
  std::vector<Datagram> d;
  for (int k = 0; k < bc.exposures; ++k)
    for (int c = 0; c < kCameras; ++c) {
      const bool lost = std::any_of(bc.losses.begin(), bc.losses.end(), [&](const LossBurst& b) {
        return (b.unit < 0 || b.unit == c / 2) && k >= b.first && k < b.first + b.count;
      });
      if (lost) continue;
      const std::int64_t latency = 800'000 + 500'000 * (c / 2) + 30'000 * (c % 2) +
                                   static_cast<std::int64_t>(1'500'000 * hash01(c, k));
      d.push_back({kHostT0 + k * kPeriodNs + 500'000 + latency, c, k});
    }
  std::stable_sort(d.begin(), d.end(),
                   [](const Datagram& a, const Datagram& b) { return a.arrival < b.arrival; });
  return d;
}

msg::MarkObservations observation(const Datagram& d) {
  return test::make_observation(d.camera / 2, 10 + d.camera,
                                kSeq0 + static_cast<std::uint32_t>(d.k), kT0Tai + d.k * kPeriodNs);
}

AlignerConfig rig8() {
  AlignerConfig c;
  for (int i = 0; i < kCameras; ++i) {
    c.camera_ids.push_back(10 + i);
    c.unit_ids.push_back(i / 2);
  }
  c.max_wait_ns = 10'000'000;  // the production wait
  c.max_pending = 64;
  return c;
}

struct Run {
  std::vector<pipeline::AlignedExposure> out;
  std::map<int, std::uint32_t> delivered;  // exposure -> mask of cameras pushed (the truth)
  std::uint64_t kernel_drops = 0;
};

// The host loop (host/app host_loop.cpp): wait for data or the aligner's deadline, read at most
// 256 datagrams with one host time, poll the aligner, process what it released. While stalled
// (descheduled) the host does nothing; the kernel queues up to the socket's capacity.
Run run_host(const BurstCase& bc, ExposureAligner& aligner) {
  const std::vector<Datagram> arrivals = stream(bc);
  auto after_stalls = [&](std::int64_t t) {
    for (const Stall& s : bc.stalls)
      if (t >= kHostT0 + s.at_ns && t < kHostT0 + s.at_ns + s.for_ns)
        t = kHostT0 + s.at_ns + s.for_ns;
    return t;
  };
  Run r;
  std::deque<Datagram> socket;
  std::size_t next = 0;
  std::int64_t clock = arrivals.front().arrival;
  for (int turns = 0;; ++turns) {
    if (turns > 10'000'000) {
      ADD_FAILURE() << "the host loop does not progress";
      break;
    }
    while (next < arrivals.size() && arrivals[next].arrival <= clock) {
      if (socket.size() < bc.socket_capacity)
        socket.push_back(arrivals[next]);
      else
        ++r.kernel_drops;
      ++next;
    }
    if (socket.empty()) {
      const std::int64_t wake =
          std::min(next < arrivals.size() ? arrivals[next].arrival
                                          : std::numeric_limits<std::int64_t>::max(),
                   aligner.next_deadline());
      if (wake == std::numeric_limits<std::int64_t>::max()) break;
      const std::int64_t woken = after_stalls(std::max(clock, wake));
      if (woken != std::max(clock, wake) ||
          (next < arrivals.size() && arrivals[next].arrival <= woken)) {
        clock = woken;
        continue;  // data came in while asleep or stalled: read it first, as the loop does
      }
      clock = woken;
    }
    const std::size_t before = r.out.size();
    for (std::size_t i = 0; i < kReadsPerCall && !socket.empty(); ++i) {
      aligner.push(observation(socket.front()), clock, r.out);
      r.delivered[socket.front().k] |= 1u << socket.front().camera;
      socket.pop_front();
    }
    aligner.poll(clock + 10'000, r.out);
    clock = after_stalls(clock + 10'000 +
                         kProcessingNs * static_cast<std::int64_t>(r.out.size() - before));
  }
  aligner.flush(r.out);
  return r;
}

// Against the truth: each exposure that reached the aligner with any camera released once, in
// order, under its own trigger sequence, with exactly the cameras delivered for it; complete
// exactly when all eight were delivered; nothing dropped, re-learned or restarted.
void expect_truth(const BurstCase& bc, ExposureAligner& aligner, const Run& r) {
  SCOPED_TRACE(bc.name);
  const std::uint32_t all = (1u << kCameras) - 1;
  std::map<int, std::uint32_t> released;
  int previous = std::numeric_limits<int>::min();
  int wrong = 0;
  for (const auto& e : r.out) {
    const int k = static_cast<int>(e.trigger_seq - kSeq0);
    EXPECT_GT(k, previous) << "released out of order or twice";
    previous = k;
    std::uint32_t mask = 0;
    for (const auto& o : e.cameras) {
      if (o.trigger_seq != e.trigger_seq && ++wrong <= 5)
        ADD_FAILURE() << "camera " << int{o.camera_id} << " of exposure " << o.trigger_seq - kSeq0
                      << " used in exposure " << k;
      mask |= 1u << (o.camera_id - 10);
    }
    EXPECT_EQ(e.missing_camera_mask, all & ~mask);
    released[k] |= mask;
  }
  int mismatched = 0;
  for (const auto& [k, mask] : r.delivered)
    if (released[k] != mask && ++mismatched <= 5)
      ADD_FAILURE() << "exposure " << k << ": delivered cameras 0x" << std::hex << mask
                    << ", released 0x" << released[k] << std::dec;
  std::uint64_t complete = 0, pushed = 0;
  for (const auto& [k, mask] : r.delivered) {
    complete += mask == all ? 1 : 0;
    pushed += static_cast<std::uint64_t>(__builtin_popcount(mask));
  }
  const auto& c = aligner.counters();
  EXPECT_EQ(c.sequence_restarts, 0u);
  EXPECT_EQ(c.sequence_offset_changes, 0u);
  EXPECT_EQ(c.dropped_duplicate, 0u);
  EXPECT_EQ(c.dropped_time_mismatch, 0u);
  EXPECT_EQ(c.dropped_late, 0u);
  EXPECT_EQ(c.dropped_quarantined, 0u);
  EXPECT_EQ(c.observations_in, pushed);
  EXPECT_EQ(c.observations_used, pushed);
  EXPECT_EQ(c.exposures_complete, complete);
  EXPECT_EQ(r.out.size(), r.delivered.size());
  test::expect_every_observation_accounted(c);
  std::printf(
      "%-34s delivered %6llu obs, %4zu exposures (%4llu complete), kernel drops %5llu | "
      "restarts %llu offset changes %llu duplicates %llu time mismatches %llu late %llu "
      "quarantined %llu partial timeout %llu overflow %llu\n",
      bc.name.c_str(), static_cast<unsigned long long>(pushed), r.delivered.size(),
      static_cast<unsigned long long>(complete), static_cast<unsigned long long>(r.kernel_drops),
      static_cast<unsigned long long>(c.sequence_restarts),
      static_cast<unsigned long long>(c.sequence_offset_changes),
      static_cast<unsigned long long>(c.dropped_duplicate),
      static_cast<unsigned long long>(c.dropped_time_mismatch),
      static_cast<unsigned long long>(c.dropped_late),
      static_cast<unsigned long long>(c.dropped_quarantined),
      static_cast<unsigned long long>(c.exposures_partial_timeout),
      static_cast<unsigned long long>(c.exposures_partial_overflow));
}

void run_case(const BurstCase& bc) {
  ExposureAligner aligner(rig8());
  const Run r = run_host(bc, aligner);
  expect_truth(bc, aligner, r);
}

TEST(ExposureAlignerBursts, BurstLossOfAUnitOrOfEveryUnitIsAGapNotARestart) {
  // Both cameras of one unit, then of every unit at once, lose 5, 50 and 400 consecutive
  // exposures (a kernel buffer overflow drops every unit's datagrams alike).
  for (const int n : {5, 50, 400}) {
    run_case({"unit 1 loses " + std::to_string(n), 3000, {{1, 1000, n}}, {}});
    run_case({"every unit loses " + std::to_string(n), 3000, {{-1, 1000, n}}, {}});
  }
  run_case({"mixed bursts",
            4000,
            {{0, 300, 5},
             {-1, 700, 50},
             {2, 1200, 400},
             {-1, 1300, 7},
             {3, 2000, 50},
             {-1, 2500, 400},
             {1, 3500, 1}},
            {}});
}

TEST(ExposureAlignerBursts, HostStallsReadTheBacklogWithoutLateOrRestarts) {
  // The host is descheduled 50, 120 and 250 ms, each stall beginning while an exposure's
  // datagrams arrive (3 or 2 of its 8 read); then it reads the socket's backlog, 256 datagrams
  // per call at one host time, that exposure's wait long expired.
  for (const std::int64_t ms : {50, 120, 250})
    run_case({"stall " + std::to_string(ms) + " ms", 3000, {}, {{2'002'600'000, ms * 1'000'000}}});
  // The same with a socket buffer of 300 datagrams (37 exposures): the kernel drops every
  // unit's datagrams after it fills, so the backlog ends in a gap of every unit.
  for (const std::int64_t ms : {50, 120, 250})
    run_case({"stall " + std::to_string(ms) + " ms, 300-datagram buffer",
              3000,
              {},
              {{2'002'600'000, ms * 1'000'000}},
              300});
  run_case({"stalls and bursts",
            6000,
            {{1, 500, 50}, {-1, 3000, 5}, {2, 4000, 400}},
            {{1'002'600'000, 200'000'000},
             {1'502'600'000, 60'000'000},
             {5'002'600'000, 250'000'000},
             {9'002'600'000, 100'000'000},
             {12'002'600'000, 180'000'000}},
            400});
}

TEST(ExposureAlignerBursts, StragglerBehindAGapDoesNotEvictTheExposureAfterIt) {
  // Exposures 101-149 of every camera are lost; of exposure 100 only camera 13's datagram got
  // through, and it arrives late, after camera 10's exposure 150 opened the exposure past the
  // gap. A fitting observation far behind takes back lone exposures ahead of it (opened by a
  // sequence nothing could judge); one opened past a gap was judged by the grid and its arrival
  // time and must stay: camera 10's exposure 150 is used.
  AlignerConfig cfg;
  cfg.camera_ids = {10, 11, 12, 13};
  ExposureAligner aligner(cfg);
  std::vector<pipeline::AlignedExposure> out;
  auto obs = [](int camera, int k) {
    return test::make_observation(0, camera, kSeq0 + static_cast<std::uint32_t>(k),
                                  kT0Tai + k * kPeriodNs);
  };
  auto host_time = [](int k) { return kHostT0 + k * kPeriodNs + 1'000'000; };
  for (int k = 0; k < 200; ++k) {
    if (k >= 100 && k < 150) continue;
    aligner.poll(host_time(k), out);
    aligner.push(obs(10, k), host_time(k), out);
    if (k == 150) aligner.push(obs(13, 100), host_time(k) + 10'000, out);  // the straggler
    for (int c = 11; c < 14; ++c)
      aligner.push(obs(c, k), host_time(k) + 20'000, out);
  }
  aligner.flush(out);
  ASSERT_EQ(out.size(), 151u);
  for (const auto& e : out) {
    const int k = static_cast<int>(e.trigger_seq - kSeq0);
    EXPECT_EQ(e.missing_camera_mask, k == 100 ? 0b0111u : 0u) << k;
  }
  EXPECT_EQ(aligner.counters().dropped_quarantined, 0u);
  EXPECT_EQ(aligner.counters().sequence_restarts, 0u);
  EXPECT_EQ(aligner.counters().sequence_offset_changes, 0u);
  test::expect_every_observation_accounted(aligner.counters());
}

TEST(ExposureAlignerBursts, SlowMotionReplayIsReleasedByTheHostWait) {
  // The fault runs deliver the 400 fps scenario at 10 fps (exposure times 2.5 ms apart, host
  // times 100 ms apart) with a 5 s wait; camera 13 is dead. The wait must be the host's (50
  // deliveries), not 5 s of exposure time (2000 exposures, longer than the run: every exposure
  // would wait for the end).
  AlignerConfig cfg;
  cfg.camera_ids = {10, 11, 12, 13};
  cfg.max_wait_ns = 5 * time::kNsPerSecond;
  cfg.max_pending = 1024;
  ExposureAligner aligner(cfg);
  constexpr std::int64_t kDeliveryNs = 100'000'000;
  std::vector<pipeline::AlignedExposure> out;
  std::map<std::uint32_t, std::int64_t> first_arrival;
  std::int64_t worst_delay = 0;
  std::int64_t now = kHostT0;
  for (std::uint32_t k = 0; k < 200; ++k, now += kDeliveryNs) {
    aligner.poll(now, out);
    const std::size_t before = out.size();
    first_arrival[kSeq0 + k] = now;
    for (int c = 0; c < 3; ++c)
      aligner.push(test::make_observation(0, 10 + c, kSeq0 + k, kT0Tai + k * kPeriodNs), now, out);
    for (std::size_t i = before; i < out.size(); ++i)
      worst_delay = std::max(worst_delay, now - first_arrival[out[i].trigger_seq]);
  }
  EXPECT_GE(out.size(), 150u) << "released during the run, not at its end";
  EXPECT_LE(worst_delay, cfg.max_wait_ns + kDeliveryNs);
  aligner.flush(out);
  ASSERT_EQ(out.size(), 200u);
  EXPECT_EQ(aligner.counters().exposures_partial_timeout, 200u);
  EXPECT_EQ(total_dropped(aligner.counters()), 0u);
}

}  // namespace
}  // namespace storetrack::ingest
