// Is a substituted input's change of the SMOOTHED trajectory significant?
// (storetrack-post --smoothed-differences-csv; docs/post-processing.md, "Differences of the
// smoothed trajectory".) Both runs (the inputs as recorded, and the substitutes) are smoothed;
// per smoothed exposure and per quantity of the smoothed CSV (position, attitude, velocity,
// acceleration, angular rate and acceleration), the difference against the standard
// uncertainty of that DIFFERENCE: the smoother is linear in its measurements, so each run's
// shared error is its loadings E on the recording's whitened factors; a substituted input is an
// independent draw (E_A E_A^T + E_B E_B^T), one not substituted the same draw ((E_B - E_A)
// (E_B - E_A)^T); the noise (the same observations, the same model) cancels, or is bounded.
#pragma once

#include <array>
#include <cstdint>
#include <cstdio>
#include <span>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "differences.hpp"
#include "smoothed_csv.hpp"
#include "storetrack/smooth/pose_smoother.hpp"

namespace storetrack::post {

/// |z| above this is flagged (the CSV's sig_k2_ columns): k = 2, ~95 % for an honest z.
inline constexpr double kSignificanceK = 2;

/// One run: its smoothed states and its written samples' poses (trigger_seq, the observations
/// used, the shared columns per input), from the same replay.
struct SmoothedRun {
  std::span<const smooth::SmoothedState> states;
  std::span<const RunPose> poses;
};

/// How a row's u was derived (the CSV's u_basis).
enum class DifferenceBasis {
  kNoiseCancels,  ///< the same observations and model over the segment: the noise cancels
  kNoiseBound,    ///< other observations, steps or configuration: (sd_A + sd_B)^2 added
  kNotDerived,    ///< u and z NaN: why_not says why
};

struct SmoothedDifferenceRow {
  std::uint32_t trigger_seq = 0;
  time::TaiNs t_ns = 0;
  int segment = 0;  ///< the recorded run's
  DifferenceBasis basis = DifferenceBasis::kNoiseCancels;
  std::string why_not;  ///< kNotDerived: a token without commas (the CSV's u_basis)
  std::array<double, kSmoothedOutputs> d{}, u{}, z{};  ///< substituted - recorded (angles wrapped)
};

/// The exposures both runs smoothed, paired by trigger_seq, in trigger_seq order.
std::vector<SmoothedDifferenceRow> smoothed_differences(const SmoothedRun& recorded,
                                                        const SmoothedRun& substituted,
                                                        const Substituted& what);

struct SmoothedDifferenceSummary {
  std::uint64_t recorded = 0, substituted = 0;  ///< smoothed states of each run
  std::uint64_t compared = 0, noise_bound = 0, not_derived = 0;
  std::array<AxisSummary, kSmoothedOutputs> quantities{};
};

SmoothedDifferenceSummary summarize(std::span<const SmoothedDifferenceRow> rows,
                                    const SmoothedRun& recorded, const SmoothedRun& substituted);

/// Header (units) and one line per compared exposure; false on a write error.
bool write_smoothed_differences_csv(std::FILE* f, std::span<const SmoothedDifferenceRow> rows);
nlohmann::json to_json(const SmoothedDifferenceSummary& s);
void print_summary(std::FILE* f, const SmoothedDifferenceSummary& s);

}  // namespace storetrack::post
