// Which processed exposures become FTI samples: never one that no camera measured, never one
// with fewer cameras than the configured minimum (issue 31: a forged datagram's lone exposure
// was written to every output with cameras_used 0). Counted by reason (stats
// "samples_withheld"), never silently.
#pragma once

#include <cstdint>

namespace storetrack::hostapp {

enum class SampleVerdict {
  kWrite,
  kNoCameraUsed,         ///< no camera contributed an identified mark (cameras_used 0)
  kFewerCamerasThanMin,  ///< 0 < cameras_used < the aligner's min_cameras
};

/// `cameras_used`: cameras whose identified marks the processor used (the sample's field);
/// `min_cameras`: the aligner's minimum (aligner/min_cameras, --min-cameras).
constexpr SampleVerdict judge_sample(int cameras_used, int min_cameras) {
  if (cameras_used <= 0) return SampleVerdict::kNoCameraUsed;
  if (cameras_used < min_cameras) return SampleVerdict::kFewerCamerasThanMin;
  return SampleVerdict::kWrite;
}

/// Exposures processed but not written to any output (iNET-X, Chapter 10, CSVs), by reason.
struct SamplesWithheld {
  std::uint64_t no_camera_used = 0;
  std::uint64_t fewer_cameras_than_min = 0;
  std::uint64_t total() const { return no_camera_used + fewer_cameras_than_min; }
  /// Counts `verdict`; true when the sample is to be written.
  bool admit(SampleVerdict verdict) {
    if (verdict == SampleVerdict::kNoCameraUsed) ++no_camera_used;
    if (verdict == SampleVerdict::kFewerCamerasThanMin) ++fewer_cameras_than_min;
    return verdict == SampleVerdict::kWrite;
  }
};

}  // namespace storetrack::hostapp
