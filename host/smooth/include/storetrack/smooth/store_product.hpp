// The store-separation data product (issue 26; docs/post-processing.md, "Data product"): from
// each smoothed state of T_p_s and its rates, the store's CG position, its displacement from
// the carriage (captive) CG position, yaw/pitch/roll of the store relative to the pylon
// (Z-Y'-X'', docs/conventions.md), the CG's velocity and acceleration (pylon axes) and the body
// rates p, q, r (store axes), against time since the release t0, each with its standard
// uncertainty split like the smoothed state's: the noise part and the shared part
// (calibration, survey and the CG offset's own uncertainty: one draw for the recording).
// First-order propagation through the Jacobians of `store_kinematics`.
#pragma once

#include <array>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "storetrack/smooth/pose_smoother.hpp"
#include "storetrack/smooth/release_time.hpp"

namespace storetrack::smooth {

/// Rows of the kinematic quantities (store_kinematics), then the product's further rows: the
/// displacement from the carriage, and in aircraft axes the CG position, the Euler angles, the
/// CG's velocity and acceleration, the angular rate and the displacement from the carriage.
inline constexpr int kKinematicsSize = 15, kProductSize = 36;
inline constexpr int kCgPosition = 0, kEulerYpr = 3, kCgVelocity = 6, kCgAccel = 9, kBodyRates = 12,
                     kCgDisplacement = 15, kCgAircraft = 18, kEulerAircraft = 21,
                     kCgVelocityAircraft = 24, kCgAccelAircraft = 27, kAngularRateAircraft = 30,
                     kCgDisplacementAircraft = 33;
using KinematicsVector = Eigen::Matrix<double, kKinematicsSize, 1>;
using KinematicsByState = Eigen::Matrix<double, kKinematicsSize, kStateSize>;
using KinematicsByCg = Eigen::Matrix<double, kKinematicsSize, 3>;
using ProductVector = Eigen::Matrix<double, kProductSize, 1>;

/// The CSV names (with units) of the product's rows, in order.
extern const std::array<const char*, kProductSize> kProductNames;

/// The store's CG in the store frame and its per-axis standard uncertainty (store survey "cg").
struct CgOffset {
  geometry::Vec3 cg_s = geometry::Vec3::Zero();
  double sigma_m = 0;
};

/// CG position, Euler angles, CG velocity and acceleration (pylon frame) and body rates of the
/// state `s`, with their Jacobians with respect to the state (attitude: left perturbation,
/// docs/conventions.md) and to cg_s (either may be null).
KinematicsVector store_kinematics(const SmoothedState& s, const geometry::Vec3& cg_s,
                                  KinematicsByState* d_state = nullptr,
                                  KinematicsByCg* d_cg = nullptr);

struct ProductSample {
  time::TaiNs t_ns = 0;
  double t_since_t0_s = 0;  ///< NaN without a release time
  int segment = 0;
  bool measured = false, step = false;
  /// Displacement rows NaN without a carriage, aircraft rows without a pylon pose.
  ProductVector value = ProductVector::Zero();
  ProductVector u_noise = ProductVector::Zero(), u_shared = ProductVector::Zero();  ///< k = 1
  ProductVector u() const { return (u_noise.array().square() + u_shared.array().square()).sqrt(); }
};

/// The product of every smoothed state. The carriage CG position is the smoothed one of the
/// last state of t0's segment before t0 - 2 u(t0); the displacement's shared part is exact (the
/// difference of loadings), its noise part the bound u_k + u_carriage (the smoother states no
/// covariance between two times). Aircraft axes: the state composed with the pylon pose T_w_p
/// solved at the same exposure (`measurements`, matched by time; NaN where it has none); shared
/// part exact (the loadings add), noise part the bound u(T_w_p part) + u(state part) (the
/// pylon's centroid noise is in both, and the smoother does not carry it apart). The velocity,
/// acceleration, angular rate and displacement in aircraft axes are the pylon-axes ones turned
/// by the same exposure's R_w_p: the pylon is surveyed rigid to the aircraft (its motion
/// relative to the aircraft is not estimated), so the rates relative to the pylon are those
/// relative to the aircraft, and R_w_p's error is a shared term like the CG's (the same
/// propagation, `aircraft_vector`); the displacement's noise bound is u_k + u_carriage per
/// aircraft axis.
std::vector<ProductSample> store_product(std::span<const SmoothedState> states,
                                         std::span<const PoseMeasurement> measurements,
                                         const ReleaseTime& release, const CgOffset& cg);

}  // namespace storetrack::smooth
