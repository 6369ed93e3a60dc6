// Writes the Chapter 10 seed of fuzz_ch10_reader with the project's own writer: TMATS, Time F1 and
// Message F0 packets of a few FtiSamples crossing a UTC second (so two Time packets), 32-bit data
// checksums, small packets. Run once to refresh seeds/ch10_reader/ (docs/reliability.md).
#include <cstdio>
#include <random>

#include "../output/fti_sample_factory.hpp"
#include "storetrack/output/chapter10_writer.hpp"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s OUT.ch10\n", argv[0]);
    return 2;
  }
  storetrack::output::Chapter10Config config;
  config.max_messages_per_packet = 3;
  config.sync = storetrack::output::Chapter10Sync::kNone;
  config.test_point = "fuzz seed";
  storetrack::output::Chapter10Writer writer;
  if (writer.open(argv[1], config) != 0) return 1;
  std::mt19937_64 rng(11);
  const std::int64_t t0_tai_ns = 1'700'000'036'990'000'000;  // 10 ms before a UTC second
  for (std::uint32_t k = 0; k < 7; ++k)
    if (writer.write(storetrack::output::testing::make_sample(k, t0_tai_ns, rng)) != 0) return 1;
  return writer.close() == 0 ? 0 : 1;
}
