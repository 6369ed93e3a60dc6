// storetrack-match-bench: cost of MarkMatcher::match per exposure (4 cameras, 23 marks, store
// separation from the simulator's fast mode, exposures replayed in order so tracking stays
// valid; docs/performance.md, "Mark matching (host/match)").
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

#include "storetrack/match/mark_matcher.hpp"
#include "storetrack/sim/simulator.hpp"

namespace {

using namespace storetrack;

struct Data {
  Data()
      : sim(sim::load_scenario(std::string(STORETRACK_SCENARIO_DIR) + "/store_separation.json"),
            3) {
    for (int k = 0; k < sim.num_exposures(); ++k) {
      std::vector<msg::MarkObservations> ex(static_cast<size_t>(sim.num_cameras()));
      for (int c = 0; c < sim.num_cameras(); ++c)
        sim.observe(k, c, ex[static_cast<size_t>(c)]);
      exposures.push_back(ex);
    }
  }
  sim::Simulator sim;
  std::vector<std::vector<msg::MarkObservations>> exposures;
};

const Data& data() {
  static const Data d;
  return d;
}

match::MarkMatcher make_matcher(const Data& d) {
  match::MarkMatcher m(d.sim.calibrated_rig(), {d.sim.pylon_survey(), d.sim.store_survey()});
  const geometry::Mat6 prior = geometry::Mat6::Identity() * 1e-4;
  m.set_prior_pose("pylon", d.sim.scenario().T_w_p, prior);
  m.set_prior_pose("store", d.sim.scenario().T_w_p * d.sim.scenario().separation.T_p_s0, prior);
  return m;
}

// One exposure through MarkMatcher::match (tracked; the restart from the priors at the end of
// the scenario is not timed).
void BM_Match(benchmark::State& state) {
  const Data& d = data();
  auto matcher = make_matcher(d);
  size_t k = 0, identified = 0;
  for (auto _ : state) {
    const match::MatchResult r = matcher.match(d.exposures[k]);
    benchmark::DoNotOptimize(r.ids.data());
    identified += static_cast<size_t>(r.identified);
    if (++k == d.exposures.size()) {
      state.PauseTiming();
      k = 0;
      matcher.reset_tracking();
      state.ResumeTiming();
    }
  }
  state.counters["identified"] =
      benchmark::Counter(static_cast<double>(identified), benchmark::Counter::kAvgIterations);
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Match);

}  // namespace

BENCHMARK_MAIN();
