// Mark identification by prediction (host app): every mark whose position can be predicted for
// this exposure (its own track, else its body's last pose, else the initial positions from the
// installation survey) is projected into each camera with the calibrated model; an observation
// takes the id of the predicted mark nearest to it when that is within the gate AND unambiguous
// (the second-nearest prediction is clearly further, and no other observation claims the same
// mark). Ambiguities are rejected (id -1, counted), never guessed.
#pragma once

#include <cstdint>
#include <map>
#include <vector>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/sim/body.hpp"

namespace storetrack::hostapp {

struct IdentifierConfig {
  double gate_px = 6.0;           ///< max distance observation - prediction
  double ambiguity_ratio = 2.0;   ///< second-nearest must be this much further
  double max_track_age_s = 0.05;  ///< older tracks are not extrapolated
};

struct IdentifierCounters {
  std::uint64_t observations = 0;
  std::uint64_t identified = 0;
  std::uint64_t unmatched = 0;      ///< nothing predicted within the gate
  std::uint64_t ambiguous = 0;      ///< two predictions too close to tell apart
  std::uint64_t conflicts = 0;      ///< two observations claimed one mark: both rejected
  std::uint64_t no_prediction = 0;  ///< exposures without any predicted mark
};

class MarkIdentifier {
 public:
  MarkIdentifier(const camera::RigCalibration& rig, const sim::RigidBodySurvey& pylon,
                 const sim::RigidBodySurvey& store, IdentifierConfig config);

  /// Initial positions (world frame) of marks, e.g. from the installation survey.
  void set_initial_positions(const std::map<int, geometry::Vec3>& p_w_by_id);

  pipeline::MarkIds identify(const pipeline::AlignedExposure& exposure);
  /// Feeds the result of the exposure just identified (tracks and body poses).
  void update(const pipeline::ExposureResult& result, time::TaiNs t_tai_ns);

  const IdentifierCounters& counters() const { return counters_; }

 private:
  struct Track {
    bool valid = false;
    time::TaiNs t = 0;
    geometry::Vec3 p_w = geometry::Vec3::Zero();
    geometry::Vec3 v_w = geometry::Vec3::Zero();
    bool v_valid = false;
  };
  bool predict(int id, time::TaiNs t, geometry::Vec3& p_w) const;

  camera::RigCalibration rig_;
  sim::RigidBodySurvey pylon_, store_;
  IdentifierConfig config_;
  std::map<int, geometry::Vec3> initial_;
  std::map<int, Track> tracks_;
  std::vector<int> ids_;  // every mark id of both bodies
  bool have_T_w_p_ = false, have_T_w_s_ = false;
  geometry::Transform T_w_p_ = geometry::Transform::Identity();
  geometry::Transform T_w_s_ = geometry::Transform::Identity();
  IdentifierCounters counters_;
};

}  // namespace storetrack::hostapp
