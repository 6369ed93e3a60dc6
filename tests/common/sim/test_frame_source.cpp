// SimFrameSource: sequence, timing, ring discipline, no allocation per frame; PGM sequences.
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

#include <unistd.h>

#include <gtest/gtest.h>

#include "storetrack/sim/frame_source.hpp"
#include "storetrack/testing/counting_allocator.hpp"

namespace storetrack::sim {
namespace {

Scenario short_scenario(int n) {
  // Appended, not operator+ of a temporary: gcc 12's -Warray-bounds false positive on the latter.
  std::string path = STORETRACK_SIM_SCENARIO_DIR;
  path += "/store_separation.json";
  Scenario sc = load_scenario(path);
  sc.num_exposures = n;
  sc.cameras.resize(2);
  return sc;
}

TEST(SimFrameSource, StartsAtTheFirstExposureAndPacesAtTheGivenRate) {
  // A unit (re)started mid-run: exposures 3..5 of the scenario with their own time stamps,
  // delivered at 50 Hz (slow motion) instead of the scenario's 400 Hz.
  const Simulator sim(short_scenario(6), 3);
  SimFrameSource src(sim, 0, 2, /*pace_realtime=*/true, /*first_exposure=*/3, /*pace_hz=*/50.0);
  ASSERT_EQ(src.start(), 0);
  frame::FrameView f;
  const time::MonotonicNs t0 = time::monotonic_now_ns();
  for (int k = 3; k < 6; ++k) {
    ASSERT_EQ(src.acquire(f, 1000), 0);
    EXPECT_EQ(f.sequence, sim.scenario().first_trigger_seq + static_cast<std::uint32_t>(k));
    EXPECT_EQ(f.timestamp_mono_ns, sim.exposure_timing(k, 0).reported_start_mono_ns);
    ASSERT_EQ(src.release(f), 0);
  }
  EXPECT_EQ(src.frames_delivered(), 3);
  EXPECT_EQ(src.acquire(f, 0), -ENODATA);
  // Three frames at 50 Hz: the third is due 40 ms after the start (at 400 Hz: 5 ms).
  EXPECT_GE(time::monotonic_now_ns() - t0, 39'000'000);
}

TEST(SimFrameSource, DeliversTheSequenceWithTimestampsAndEndsWithNoData) {
  const Simulator sim(short_scenario(5), 3);
  SimFrameSource src(sim, 1, 2);
  frame::FrameView f;
  EXPECT_EQ(src.acquire(f, 0), -EINVAL);  // not started
  ASSERT_EQ(src.start(), 0);
  std::vector<std::uint8_t> reference;
  for (int k = 0; k < 5; ++k) {
    ASSERT_EQ(src.acquire(f, 0), 0);
    EXPECT_EQ(f.sequence, sim.scenario().first_trigger_seq + static_cast<std::uint32_t>(k));
    EXPECT_EQ(f.width, 1920);
    EXPECT_EQ(f.height, 1024);
    EXPECT_EQ(f.exposure_ns, sim.scenario().exposure_ns);
    EXPECT_EQ(f.timestamp_mono_ns, sim.exposure_timing(k, 1).reported_start_mono_ns);
    sim.render(k, 1, reference);  // deterministic: the same frame
    EXPECT_EQ(0, std::memcmp(reference.data(), f.pixels, reference.size()));
    EXPECT_EQ(src.release(f), 0);
    EXPECT_EQ(src.release(f), -EINVAL);  // double release
  }
  EXPECT_EQ(src.acquire(f, 0), -ENODATA);
  EXPECT_EQ(src.stop(), 0);
}

TEST(SimFrameSource, RingIsFiniteAndPerFramePathDoesNotAllocate) {
  const Simulator sim(short_scenario(12), 3);
  SimFrameSource src(sim, 0, 3);
  ASSERT_EQ(src.start(), 0);
  frame::FrameView a, b, c, d;
  ASSERT_EQ(src.acquire(a, 0), 0);  // warm-up frame
  ASSERT_EQ(src.release(a), 0);
  const long before = storetrack::testing::allocation_count();
  ASSERT_EQ(src.acquire(a, 0), 0);
  ASSERT_EQ(src.acquire(b, 0), 0);
  ASSERT_EQ(src.acquire(c, 0), 0);
  EXPECT_EQ(src.acquire(d, 0), -EBUSY);
  EXPECT_NE(a.buffer_index, b.buffer_index);
  EXPECT_EQ(src.release(b), 0);
  ASSERT_EQ(src.acquire(d, 0), 0);
  EXPECT_EQ(d.buffer_index, b.buffer_index);
  EXPECT_EQ(storetrack::testing::allocation_count() - before, 0);
  EXPECT_EQ(src.release(a), 0);
  EXPECT_EQ(src.release(c), 0);
  EXPECT_EQ(src.release(d), 0);
}

TEST(SimFrameSource, PooledBackgroundErasesEarlierSpotsAndDrawsEachExposuresSpotsAtTruth) {
  // store_separation: the store's spots move between exposures, so a buffer reused for exposure
  // k + pool holds spots where exposure k had none: they must be gone, the background exact.
  constexpr int kPool = 2;
  const Simulator sim(short_scenario(8), 3);
  SimFrameSource src(sim, 0, 4, false, 0, 0, kPool);
  ASSERT_EQ(src.start(), 0);
  const int w = 1920, h = 1024;
  std::vector<std::vector<std::uint8_t>> background(kPool, std::vector<std::uint8_t>(w * h));
  SpotRenderer renderer;
  for (int i = 0; i < kPool; ++i)
    sim.render_background_into(i, 0, background[i].data(), w, renderer);
  std::vector<Spot> spots;
  frame::FrameView f;
  for (int k = 0; k < 8; ++k) {
    ASSERT_EQ(src.acquire(f, 0), 0);
    sim.spots(k, 0, spots);
    ASSERT_FALSE(spots.empty());
    std::vector<bool> in_box(static_cast<std::size_t>(w) * h, false);
    for (const Spot& s : spots) {
      const PixelBox b = spot_box(s, w, h);
      for (int y = b.y0; y < b.y1; ++y)
        for (int x = b.x0; x < b.x1; ++x)
          in_box[static_cast<std::size_t>(y) * w + x] = true;
      if (b.empty() || s.x_px < 3 || s.y_px < 3 || s.x_px > w - 4 || s.y_px > h - 4) continue;
      // The spot is drawn where the truth puts it: the pixel at its centre stands clearly
      // above the background there (a 20000 e- spot on a 4 px disc: hundreds of e- per pixel).
      const int cx = static_cast<int>(std::lround(s.x_px)),
                cy = static_cast<int>(std::lround(s.y_px));
      EXPECT_GE(f.pixels[cy * w + cx], background[k % kPool][cy * w + cx] + 10)
          << "exposure " << k << " spot at " << s.x_px << ", " << s.y_px;
    }
    long differ = 0;
    for (std::size_t i = 0; i < in_box.size(); ++i)
      differ += !in_box[i] && f.pixels[i] != background[k % kPool][i];
    EXPECT_EQ(differ, 0) << "exposure " << k << ": pixels outside its spots not the background";
    ASSERT_EQ(src.release(f), 0);
  }
}

TEST(SimFrameSource, PooledBackgroundKeepsExposureKInBufferKModPoolAndDoesNotAllocate) {
  const Simulator sim(short_scenario(12), 3);
  SimFrameSource src(sim, 0, 4, false, 0, 0, /*background_pool=*/2);
  ASSERT_EQ(src.start(), 0);
  frame::FrameView a, b, c;
  ASSERT_EQ(src.acquire(a, 0), 0);  // warm-up frame
  ASSERT_EQ(src.release(a), 0);
  const long before = storetrack::testing::allocation_count();
  ASSERT_EQ(src.acquire(a, 0), 0);       // exposure 1: buffer 1
  ASSERT_EQ(src.acquire(b, 0), 0);       // exposure 2: buffer 0
  EXPECT_EQ(src.acquire(c, 0), -EBUSY);  // exposure 3 needs buffer 1, still held
  ASSERT_EQ(src.release(a), 0);
  ASSERT_EQ(src.acquire(c, 0), 0);
  EXPECT_EQ(c.sequence, sim.scenario().first_trigger_seq + 3u);
  ASSERT_EQ(src.release(b), 0);
  ASSERT_EQ(src.release(c), 0);
  EXPECT_EQ(storetrack::testing::allocation_count(), before);
}

TEST(FrameSequence, PgmAndTriggerFileRoundTrip) {
  const Simulator sim(short_scenario(3), 9);
  const std::string dir = (std::filesystem::temp_directory_path() /
                           ("storetrack_sim_seq_" + std::to_string(::getpid())))
                              .string();
  write_frame_sequence(sim, 0, dir);
  std::ifstream triggers(dir + "/triggers.csv");
  std::string header, line;
  std::getline(triggers, header);
  EXPECT_EQ(header.rfind("frame,trigger_seq,trigger_tai_ns,reported_start_tai_ns", 0), 0u);
  std::vector<std::uint8_t> expected;
  for (int k = 0; k < 3; ++k) {
    ASSERT_TRUE(std::getline(triggers, line));
    EXPECT_EQ(
        line.rfind(std::to_string(k) + "," + std::to_string(sim.scenario().first_trigger_seq + k) +
                       "," + std::to_string(sim.trigger_tai_ns(k)),
                   0),
        0u)
        << line;
    char name[64];
    std::snprintf(name, sizeof name, "/frame_%06d.pgm", k);
    int w = 0, h = 0;
    const std::vector<std::uint8_t> px = read_pgm(dir + name, w, h);
    EXPECT_EQ(w, 1920);
    EXPECT_EQ(h, 1024);
    sim.render(k, 0, expected);
    EXPECT_EQ(px, expected);
  }
  EXPECT_FALSE(std::getline(triggers, line));
  // Truncated files are rejected with the file name.
  {
    std::ofstream bad(dir + "/bad.pgm", std::ios::binary);
    bad << "P5\n10 10\n255\n" << std::string(20, 'x');
  }
  int w = 0, h = 0;
  try {
    read_pgm(dir + "/bad.pgm", w, h);
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.pgm"), std::string::npos);
  }
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace storetrack::sim
