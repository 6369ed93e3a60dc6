#include "sample_compare.hpp"

#include <algorithm>
#include <array>
#include <span>

#include "storetrack/output/fti_parameter_block.hpp"

namespace storetrack::post {

namespace {

std::int64_t recorded_trigger_seq(const std::vector<std::uint8_t>& block) {
  msg::FtiSample s;
  if (output::decode_fti_parameter_block(block, s) != 0) return -1;
  return s.trigger_seq;
}

}  // namespace

SampleComparison compare_samples(const std::vector<msg::FtiSample>& replayed,
                                 const std::vector<RecordedSample>& recorded, std::size_t keep) {
  SampleComparison c;
  c.replayed = replayed.size();
  c.recorded = recorded.size();
  std::array<std::uint8_t, output::kFtiParameterBlockBytes> block{};
  for (std::size_t i = 0; i < std::min(c.replayed, c.recorded); ++i) {
    const int n = output::encode_fti_parameter_block(replayed[i], block);
    const std::span<const std::uint8_t> encoded(block.data(), static_cast<std::size_t>(n));
    const std::vector<std::uint8_t>& live = recorded[i].block;
    if (std::ranges::equal(encoded, live)) {
      ++c.identical;
      continue;
    }
    ++c.different;
    if (c.first_differences.size() >= keep) continue;
    const auto [at, unused] = std::ranges::mismatch(encoded, live);
    c.first_differences.push_back({i, replayed[i].trigger_seq, recorded_trigger_seq(live),
                                   static_cast<std::size_t>(at - encoded.begin()), recorded[i].file,
                                   recorded[i].packet_offset});
  }
  return c;
}

}  // namespace storetrack::post
