// One exposure of the rig, as grouped by the host's aligner (host/ingest) and consumed by the
// ExposureProcessor (host/pipeline). Shared contract between host-io and host-geometry
// (TEAM.md, "host").
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

#include "storetrack/msg/messages.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::pipeline {

/// Observations of all cameras triggered by the same edge (same trigger_seq).
struct AlignedExposure {
  std::uint32_t trigger_seq = 0;
  /// One entry per camera that delivered this exposure, any order; camera_id identifies the
  /// camera in the RigCalibration. Empty mark lists are valid (camera saw nothing).
  std::vector<msg::MarkObservations> cameras;
  /// Bit i set: the i-th camera of the RigCalibration (rig.cameras[i]) did not deliver this
  /// exposure before the aligner's deadline.
  std::uint32_t missing_camera_mask = 0;
  /// Bit i set: rig.cameras[i] was declared moved by the calibration health monitor before
  /// this exposure and contributed marks to it (exclude mode: was dropped from it). Set by
  /// CalibrationHealthGuard::filter; the sample's status bit calibration_moved.
  std::uint32_t calibration_moved_mask = 0;
  /// Exposure mid-point (start + duration / 2) of the earliest-starting delivered camera, TAI ns;
  /// INT64_MIN when no camera delivered. Each camera's own mid-point is in `cameras`.
  time::TaiNs exposure_mid_tai_ns = std::numeric_limits<time::TaiNs>::min();
  /// True when the aligner closed the exposure on its deadline rather than on completeness.
  bool closed_by_timeout = false;
  /// Host monotonic time at which the last of its observations reached the aligner (the start
  /// of the host's latency, docs/performance.md); 0 when not made by the aligner.
  time::MonotonicNs last_arrival_mono_ns = 0;
};

/// Exposure mid-point of one camera's observations (docs/conventions.md, "Time").
inline time::TaiNs exposure_mid_tai_ns(const msg::MarkObservations& obs) {
  return obs.exposure_start_tai_ns + static_cast<time::TaiNs>(obs.exposure_duration_ns / 2);
}

}  // namespace storetrack::pipeline
