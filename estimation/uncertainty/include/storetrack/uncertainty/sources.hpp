// Uncertainty sources of the budget (docs/conventions.md, "Uncertainty"; docs/uncertainty.md).
#pragma once

#include <array>

namespace storetrack::uncertainty {

/// Independent contributions whose variances add (GUM JCGM 100:2008, 5.1.2 with uncorrelated
/// input groups). kSurvey is the body-mark survey (registration of the pylon/store frame); the
/// FTI budget reports it together with kExtrinsic ("extrinsic/world registration"). kProcess is
/// the unmodelled acceleration of an extrapolated pose (PoseTracker); zero for a measured one.
enum class Source : int {
  kCentroid = 0,
  kIntrinsic = 1,
  kExtrinsic = 2,
  kSync = 3,
  kSurvey = 4,
  kProcess = 5
};
inline constexpr int kNumSources = 6;

inline constexpr std::array<const char*, kNumSources> kSourceNames = {
    "centroid", "intrinsic", "extrinsic", "sync", "survey", "process"};

inline constexpr int index(Source s) {
  return static_cast<int>(s);
}

}  // namespace storetrack::uncertainty
