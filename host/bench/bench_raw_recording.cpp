// storetrack-host-raw-bench: what recording the raw observations costs the host's real-time
// thread per exposure (docs/fti-output.md, "Cost of the raw channel"). One iteration is the
// host's work for one exposure of the store-separation scenario (4 cameras, 23 marks): receive
// its 4 datagrams from a loopback UDP socket through UdpReceiver (decode, source checks and,
// when on, the raw hook that stamps and queues each datagram), process the exposure (matching,
// geometry, uncertainty) and hand the sample to the RecordingWriter, whose own thread writes
// the Chapter 10 file. Arg 0: raw recording off, 1: on. The datagrams are sent ahead in batches
// of 64 exposures outside the timing. Run with repetitions and random interleaving and compare
// the medians (the machine is shared: the ratio of one run is what is stated).
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <filesystem>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

#include "recording_writer.hpp"
#include "simulated_exposures.hpp"
#include "storetrack/ingest/receivers.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/sim/simulator.hpp"

namespace {

using namespace storetrack;

using Datagrams = std::vector<std::vector<std::vector<std::uint8_t>>>;  // [exposure][camera]

// The units' datagrams of every exposure of the store-separation run, numbered in sending order.
const Datagrams& datagrams() {
  static const Datagrams all = [] {
    Datagrams out;
    std::uint32_t seq = 0;
    for (const pipeline::AlignedExposure& ex : bench::store_separation().exposures) {
      std::vector<std::vector<std::uint8_t>> grams;
      for (const msg::MarkObservations& obs : ex.cameras) {
        std::array<std::uint8_t, msg::kMaxDatagramBytes> buf{};
        const int n = msg::encode_datagram(obs, buf, seq++);
        grams.emplace_back(buf.begin(), buf.begin() + std::max(n, 0));
      }
      out.push_back(grams);
    }
    return out;
  }();
  return all;
}

void BM_HostExposureWithRecording(benchmark::State& state) {
  const bool raw = state.range(0) != 0;
  const bench::SimulatedExposures& d = bench::store_separation();
  const Datagrams& grams = datagrams();
  pipeline::ExposureProcessor proc = bench::make_processor(d.sim);

  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("st_raw_bench_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  hostapp::RecordingWriter recording;
  output::Chapter10Config cfg;
  cfg.raw_observations = raw;
  cfg.sync = output::Chapter10Sync::kNone;  // the disk is not what is measured
  if (recording.open_ch10((dir / "bench.ch10").string(), cfg) != 0) {
    state.SkipWithError("cannot create the Chapter 10 file");
    return;
  }
  recording.start();

  ingest::UdpReceiver rx;
  if (rx.open("127.0.0.1", 0, "", "", 16 << 20) != 0) {
    state.SkipWithError("cannot open the UDP socket");
    return;
  }
  if (raw) {
    rx.set_raw_handler([&](const msg::RawObservation& r, std::span<const std::uint8_t> b) {
      recording.push_raw(r, b);
    });
  }
  const int tx = ::socket(AF_INET, SOCK_DGRAM, 0);
  sockaddr_in dst{};
  dst.sin_family = AF_INET;
  dst.sin_port = htons(rx.port());
  inet_pton(AF_INET, "127.0.0.1", &dst.sin_addr);

  constexpr std::size_t kBatch = 64;
  std::size_t k = 0, in_batch = kBatch, received = 0;
  for (auto _ : state) {
    if (in_batch == kBatch) {  // queue the next 64 exposures' datagrams in the socket
      state.PauseTiming();
      for (std::size_t j = 0; j < kBatch; ++j)
        for (const auto& g : grams[(k + j) % d.exposures.size()])
          ::sendto(tx, g.data(), g.size(), 0, reinterpret_cast<const sockaddr*>(&dst), sizeof dst);
      in_batch = 0;
      state.ResumeTiming();
    }
    const std::size_t cameras = d.exposures[k].cameras.size();
    std::size_t got = 0;
    rx.receive([&](const msg::AnyMessage&) { ++got; }, static_cast<int>(cameras));
    received += got;
    const pipeline::ExposureResult r = proc.process(d.exposures[k]);
    hostapp::RecordingItem item;
    item.sample = r.sample;
    recording.push(std::move(item));
    ++in_batch;
    if (++k == d.exposures.size()) {
      state.PauseTiming();
      k = 0;
      proc.reset_tracking();
      state.ResumeTiming();
    }
  }
  recording.stop();
  ::close(tx);
  const auto rc = recording.counters();
  const auto& cc = recording.ch10().counters();
  state.counters["datagrams"] =
      benchmark::Counter(static_cast<double>(received), benchmark::Counter::kAvgIterations);
  state.counters["raw_written"] = static_cast<double>(cc.raw_messages_written);
  state.counters["raw_dropped"] =
      static_cast<double>(rc.raw_dropped_queue_full + rc.raw_dropped_queue_bytes);
  state.counters["samples_dropped"] = static_cast<double>(rc.items_dropped_queue_full);
  state.SetItemsProcessed(state.iterations());
  std::filesystem::remove_all(dir);
}
BENCHMARK(BM_HostExposureWithRecording)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
