// Internals of the pendulum identification shared by its translation units.
#pragma once

#include <array>
#include <vector>

#include "storetrack/eval/pendulum.hpp"

namespace storetrack::eval::detail {

/// A run prepared for the fit: unique exposure times and, per sample, its time and mark slot.
struct PreparedRun {
  const PendulumRun* run = nullptr;
  std::vector<double> times_s;  ///< unique, ascending, since the run's first sample
  std::vector<int> time_index;  ///< per sample
  std::vector<int> mark_slot;   ///< per sample: index into PendulumState::mark_ids
};

/// The model's parameters as the solver holds them.
struct PendulumState {
  std::array<double, 2> shared{};           ///< L = l2^2/l1 [m], gamma [1/s]
  std::vector<std::array<double, 2>> run;   ///< theta0 [rad], release [s]
  std::array<double, 3> pivot{}, normal{};  ///< world frame
  std::vector<std::array<double, 3>> mark;  ///< r [m], phi [rad], h [m]
  std::vector<int> mark_ids;                ///< ascending
  std::vector<bool> clockwise;              ///< per run
};

/// One sample's dynamic error and what it is binned by.
struct SampleError {
  geometry::Vec3 error_m = geometry::Vec3::Zero();  ///< measured - reference
  geometry::Vec3 u_reference_m = geometry::Vec3::Zero();
  geometry::Vec3 u_stated_m = geometry::Vec3::Zero();
  double speed_m_s = 0;
  double axis_distance_m = 0;  ///< from the reference camera's optical axis (if given)
  bool clockwise = true;
};

/// The dynamic table (overall, per direction, model error) and the bins into `result`.
void summarise_dynamic_errors(const std::vector<SampleError>& samples, PendulumResult& result);

std::vector<PreparedRun> prepare_runs(const std::vector<PendulumRun>& runs,
                                      std::vector<int>& mark_ids);

/// Initial values from the data (plane by PCA, pivot by a circle fit, the dynamics by a linear
/// fit of the angular acceleration); throws EvalInputError for a run too short to identify.
PendulumState initial_state(const std::vector<PreparedRun>& runs, const std::vector<int>& mark_ids,
                            const PendulumOptions& options);

}  // namespace storetrack::eval::detail
