// The parts of the noise-floor evaluation (noise_floor.cpp, noise_floor_image.cpp).
#pragma once

#include <cstdint>
#include <vector>

#include "storetrack/eval/noise_floor.hpp"

namespace storetrack::eval {

struct ChiInterval {
  double low = 0, high = 0;
};
/// Two-sided interval of s / sigma for `dof` degrees of freedom at `level`:
/// sqrt(chi2_{(1-+level)/2}(dof) / dof) (the tree's chi_square_quantile).
ChiInterval ratio_interval(std::int64_t dof, double level);

geometry::Vec3 camera_centre_w(const camera::CalibratedCamera& c);

/// Each inner vector: one evaluated mark's samples (one per exposure), ascending mark id.
using EvaluatedSamples = std::vector<std::vector<const MarkSample*>>;

/// Per camera: reprojection residuals, the centroid's scatter over time against its stated
/// sigma; or the note why the record does not allow it.
void evaluate_image_coordinates(const MarksRecording& record, const EvaluatedSamples& marks,
                                NoiseFloorResult& r);
/// Seed 002 eq. (3): stereo angle and e_theta per mark and camera pair that saw it.
void evaluate_stereo_angles(const EvaluatedSamples& marks, const camera::RigCalibration& rig,
                            NoiseFloorResult& r);
/// Seed 002 eq. (4): every pair of evaluated marks, against the surveyed distance.
void evaluate_distances(const EvaluatedSamples& marks, const survey::RigidBodySurvey& reference,
                        NoiseFloorResult& r);

}  // namespace storetrack::eval
