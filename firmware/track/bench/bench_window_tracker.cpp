// bench_window_tracker: time per frame of the full-frame centroider and of the predicted-window
// tracker on the same frames: the last kFrames exposures of a store-separation scenario (the
// fastest part of the run), rendered once by the simulator for the camera that sees the most
// marks. Two scenarios, the benchmarks' second argument: 19, store_separation (19 marks seen
// on average), and 64, store_separation_64 (its denser survey: 63-64 seen). One benchmark iteration
// is the whole sequence (the tracker starts from nothing, so its first frame and every
// full_frame_interval-th are full ones, as on the unit); the frames (2 MB each, kFrames of them)
// are far larger than the caches, so each is read from memory as a freshly captured frame would be.
// Counters: s_per_frame (the figure to compare), the tracker's full frames per sequence by cause,
// windows per frame.
//
//   bench_window_tracker --benchmark_repetitions=9 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <cstdint>
#include <cstring>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "storetrack/centroid/centroider.hpp"
#include "storetrack/sim/simulator.hpp"
#include "storetrack/track/window_tracker.hpp"

namespace {

namespace sim = storetrack::sim;
namespace track = storetrack::track;
using storetrack::centroid::Blob;

constexpr int kFrames = 80;  // two periods of the default full_frame_interval

struct Frames {
  explicit Frames(const std::string& scenario)
      : simulator(
            sim::load_scenario(std::string(STORETRACK_SCENARIO_DIR) + "/" + scenario + ".json"),
            7) {
    std::vector<sim::Spot> spots;
    std::size_t best = 0;
    for (int c = 0; c < simulator.num_cameras(); ++c) {
      simulator.spots(simulator.num_exposures() / 2, c, spots);
      if (spots.size() > best) {
        best = spots.size();
        camera = c;
      }
    }
    const auto& in =
        simulator.true_rig().cameras[static_cast<std::size_t>(camera)].model.intrinsics();
    width = in.width;
    height = in.height;
    sensor = simulator.scenario().optics.sensor;
    sim::SpotRenderer renderer;
    const int first = simulator.num_exposures() - kFrames;
    for (int k = first; k < simulator.num_exposures(); ++k) {
      images.emplace_back(static_cast<std::size_t>(width) * height);
      simulator.render_into(k, camera, images.back().data(), width, renderer);
      times_ns.push_back(simulator.exposure_timing(k, camera).reported_start_tai_ns);
      simulator.spots(k, camera, spots);
      marks += static_cast<double>(spots.size());
    }
    marks /= kFrames;
  }
  storetrack::frame::FrameView view(int i) const {
    storetrack::frame::FrameView f;
    f.pixels = images[static_cast<std::size_t>(i)].data();
    f.width = width;
    f.height = height;
    f.stride_bytes = width;
    return f;
  }
  /// refine = false: threshold moments only, to show what the per-mark refinement costs.
  storetrack::centroid::CentroidConfig centroid_config(bool refine = true) const {
    storetrack::centroid::CentroidConfig config;
    config.refine = refine;
    config.read_noise_e = sensor.read_noise_e;
    config.gain_e_per_dn = sensor.gain_e_per_dn;
    config.black_level_dn = sensor.black_level_dn;
    config.saturation_dn = sensor.full_scale_dn;
    return config;
  }

  sim::Simulator simulator;
  sim::SensorModel sensor;
  int camera = 0, width = 0, height = 0;
  double marks = 0;  // mean visible marks per frame
  std::vector<std::vector<std::uint8_t>> images;
  std::vector<std::int64_t> times_ns;
};

/// The frames of the scenario named by its nominal mark count (19 or 64), rendered on first use
/// (160 MB each), so a filtered run renders only the one it needs.
const Frames& frames(std::int64_t marks = 19) {
  static std::map<std::int64_t, std::unique_ptr<const Frames>> all;
  std::unique_ptr<const Frames>& f = all[marks];
  if (!f)
    f = std::make_unique<const Frames>(marks == 64 ? "store_separation_64" : "store_separation");
  return *f;
}

void per_frame_counters(benchmark::State& state, const Frames& f) {
  state.counters["s_per_frame"] = benchmark::Counter(
      kFrames, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
  state.counters["marks"] = f.marks;
  state.counters["camera"] = f.camera;
}

void BM_FullFrame(benchmark::State& state) {
  const Frames& f = frames(state.range(1));
  storetrack::centroid::Centroider centroider(f.centroid_config(state.range(0) != 0), f.width,
                                              f.height);
  std::vector<Blob> blobs(128);
  long found = 0;  // blobs of the last sequence: does the centroider find the marks seen?
  for (auto _ : state) {
    found = 0;
    for (int i = 0; i < kFrames; ++i) {
      const int n = centroider.process(f.view(i), blobs);
      benchmark::DoNotOptimize(n);
      found += n;
    }
    benchmark::ClobberMemory();
  }
  per_frame_counters(state, f);
  state.counters["blobs"] = static_cast<double>(found) / kFrames;
}
// Args: refinement (1 the unit's centroider, 0 threshold moments only), scenario (19 or 64).
BENCHMARK(BM_FullFrame)
    ->Args({1, 19})
    ->Args({0, 19})
    ->Args({1, 64})
    ->Args({0, 64})
    ->Unit(benchmark::kMillisecond);

void BM_Windowed(benchmark::State& state) {
  const Frames& f = frames(state.range(1));
  track::WindowTracker tracker({}, f.centroid_config(state.range(0) != 0), f.width, f.height);
  std::vector<Blob> blobs(128);
  for (auto _ : state) {
    tracker.reset();
    for (int i = 0; i < kFrames; ++i)
      benchmark::DoNotOptimize(
          tracker.process(f.view(i), f.times_ns[static_cast<std::size_t>(i)], blobs));
    benchmark::ClobberMemory();
  }
  per_frame_counters(state, f);
  const track::WindowTrackerStats& st = tracker.stats();
  const double sequences = static_cast<double>(state.iterations());
  state.counters["full_per_seq"] = static_cast<double>(st.full_frames) / sequences;
  for (int c = 0; c < track::kFullFrameCauses; ++c) {
    if (st.full_frames_by_cause[c] == 0) continue;
    std::string name =
        std::string("full_") + track::to_string(static_cast<track::FullFrameCause>(c));
    for (char& ch : name)
      if (ch == ' ') ch = '_';
    state.counters[name] = static_cast<double>(st.full_frames_by_cause[c]) / sequences;
  }
  state.counters["windows_per_frame"] =
      static_cast<double>(st.windows_tried) / std::max<double>(1.0, double(st.windowed_frames));
}
BENCHMARK(BM_Windowed)
    ->Args({1, 19})
    ->Args({0, 19})
    ->Args({1, 64})
    ->Args({0, 64})
    ->Unit(benchmark::kMillisecond);

// The centroider's ROI mode with no ROI: the fixed cost of a call. (Before the ROI mode
// estimated the background only in the tiles under its ROIs, this was the whole frame's
// background estimate, paid by every windowed frame: 22 us, 0.14x of a full frame.)
void BM_BackgroundOnly(benchmark::State& state) {
  const Frames& f = frames();
  storetrack::centroid::Centroider centroider(f.centroid_config(), f.width, f.height);
  std::vector<Blob> blobs(128);
  for (auto _ : state) {
    for (int i = 0; i < kFrames; ++i)
      benchmark::DoNotOptimize(
          centroider.process(f.view(i), std::span<const storetrack::centroid::Roi>(), blobs));
    benchmark::ClobberMemory();
  }
  per_frame_counters(state, f);
}
BENCHMARK(BM_BackgroundOnly)->Unit(benchmark::kMillisecond);

// The floor: a memcpy of each frame (the yardstick for the full-frame pass).
void BM_MemcpyFloor(benchmark::State& state) {
  const Frames& f = frames();
  std::vector<std::uint8_t> copy(static_cast<std::size_t>(f.width) * f.height);
  for (auto _ : state) {
    for (int i = 0; i < kFrames; ++i) {
      std::memcpy(copy.data(), f.images[static_cast<std::size_t>(i)].data(), copy.size());
      benchmark::DoNotOptimize(copy.data());
    }
    benchmark::ClobberMemory();
  }
  per_frame_counters(state, f);
}
BENCHMARK(BM_MemcpyFloor)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
