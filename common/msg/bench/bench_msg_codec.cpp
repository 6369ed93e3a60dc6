// Codec timings for the unit's per-frame path (encode) and the host's receive path (decode,
// CAN FD reassembly): one exposure of 23 marks, as in the store-separation test point.
#include <benchmark/benchmark.h>

#include <array>
#include <random>

#include "storetrack/msg/canfd_codec.hpp"
#include "storetrack/msg/udp_codec.hpp"

namespace msg = storetrack::msg;

namespace {

msg::MarkObservations exposure(int marks) {
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  msg::MarkObservations m;
  m.unit_id = 1;
  m.camera_id = 2;
  m.trigger_seq = 12345;
  m.exposure_start_tai_ns = 1'800'000'000'000'000'000;
  m.exposure_start_mono_ns = 5'000'000'000'000;
  m.exposure_duration_ns = 200'000;
  m.clock_state = 2;
  m.mark_count = static_cast<std::uint8_t>(marks);
  for (int i = 0; i < marks; ++i) {
    auto& o = m.marks[static_cast<std::size_t>(i)];
    o.x_px = static_cast<float>(1919.0 * u(rng));
    o.y_px = static_cast<float>(1023.0 * u(rng));
    o.sigma_px = static_cast<float>(0.01 + 0.09 * u(rng));
    o.peak = 200;
    o.diameter_px = 8.0f;
  }
  return m;
}

void BM_UdpEncode(benchmark::State& state) {
  const auto m = exposure(static_cast<int>(state.range(0)));
  std::array<std::uint8_t, msg::kMaxDatagramBytes> buf;
  for (auto _ : state) {
    benchmark::DoNotOptimize(msg::encode_datagram(m, buf, 7));
    benchmark::ClobberMemory();
  }
}
BENCHMARK(BM_UdpEncode)->Arg(23)->Arg(64);

void BM_UdpDecode(benchmark::State& state) {
  const auto m = exposure(static_cast<int>(state.range(0)));
  std::array<std::uint8_t, msg::kMaxDatagramBytes> buf;
  const int n = msg::encode_datagram(m, buf, 7);
  msg::AnyMessage out;
  for (auto _ : state) {
    benchmark::DoNotOptimize(
        msg::decode_datagram(std::span(buf).first(static_cast<std::size_t>(n)), out));
    benchmark::ClobberMemory();
  }
}
BENCHMARK(BM_UdpDecode)->Arg(23)->Arg(64);

void BM_CanFdEncode(benchmark::State& state) {
  const auto m = exposure(static_cast<int>(state.range(0)));
  std::array<msg::CanFdFrame, msg::kCanFdMaxFramesPerMessage> frames;
  for (auto _ : state) {
    benchmark::DoNotOptimize(msg::encode_canfd(m, frames));
    benchmark::ClobberMemory();
  }
}
BENCHMARK(BM_CanFdEncode)->Arg(23)->Arg(64);

void BM_CanFdReassemble(benchmark::State& state) {
  auto m = exposure(static_cast<int>(state.range(0)));
  std::array<msg::CanFdFrame, msg::kCanFdMaxFramesPerMessage> frames;
  msg::CanFdReassembler reassembler;
  std::optional<msg::AnyMessage> done;
  std::int64_t now = 0;
  for (auto _ : state) {
    state.PauseTiming();
    ++m.trigger_seq;
    const int n = msg::encode_canfd(m, frames);
    state.ResumeTiming();
    for (int i = 0; i < n; ++i)
      reassembler.push(frames[static_cast<std::size_t>(i)], now += 1000, done);
    benchmark::DoNotOptimize(done);
  }
}
BENCHMARK(BM_CanFdReassemble)->Arg(23)->Arg(64);

}  // namespace

BENCHMARK_MAIN();
