// The replay's samples against the live run's, as the recording holds them: each replayed sample
// encoded as the FTI parameter block the host wrote, compared byte for byte, in order.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "recording.hpp"
#include "storetrack/msg/messages.hpp"

namespace storetrack::post {

struct SampleDifference {
  std::size_t index = 0;  ///< position in both sequences
  std::uint32_t replayed_trigger_seq = 0;
  std::int64_t recorded_trigger_seq = -1;  ///< -1: the recorded block does not decode
  std::size_t first_byte = 0;              ///< offset in the block of the first byte that differs
  std::string file;                        ///< where the recorded block is
  std::size_t packet_offset = 0;
};

struct SampleComparison {
  std::size_t replayed = 0, recorded = 0;
  std::size_t identical = 0, different = 0;  ///< over the first min(replayed, recorded)
  std::vector<SampleDifference> first_differences;
  bool same() const { return different == 0 && replayed == recorded; }
};

/// Compares replayed[i] with recorded[i] for every i both have; keeps the first `keep`
/// differences.
SampleComparison compare_samples(const std::vector<msg::FtiSample>& replayed,
                                 const std::vector<RecordedSample>& recorded, std::size_t keep = 5);

}  // namespace storetrack::post
