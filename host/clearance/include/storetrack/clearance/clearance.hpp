// Store-to-aircraft clearance per sample: for each aircraft part, the minimum distance to the
// store posed by T_p_s, the two closest points, the feature pair, the contact normal, the
// distance's standard uncertainty from the 6x6 covariance of T_p_s, and the k = 2 lower bound
// with the feature-switch rule of docs/clearance.md.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "storetrack/clearance/geometry_file.hpp"
#include "storetrack/clearance/mesh_bvh.hpp"
#include "storetrack/geometry/transform.hpp"

namespace storetrack::clearance {

inline constexpr double kCoverageFactor = 2.0;  ///< k of the lower bound (GUM, docs/conventions.md)
/// One-sided miss probability of the k = 2 lower bound of one Gaussian feature: Phi(-2).
inline constexpr double kLowerBoundMiss = 0.022750131948179209;
/// Two candidate pairs whose distance errors are correlated at least this much are one feature
/// (the same vertex on several triangles, neighbouring facets of one smooth contact); merging
/// two such variables under-counts the miss probability by at most 4 % of kLowerBoundMiss
/// (docs/clearance.md, "Feature switch").
inline constexpr double kSameFeatureCorrelation = 0.999;
/// A pair is left out of the bound's sum when its distance is more than this many of its own u
/// beyond the single-feature bound d_min - 2 u_min: its term would be below Phi(-4) = 3.2e-5.
/// Pairs are searched within this many u_bound (a bound on every pair's u) of that bound.
inline constexpr double kCandidateReachSigmas = 4.0;

struct PartClearance {
  // Names owned by the ClearanceModel (no string is copied per sample): valid while the model
  // that returned this result lives and is not moved.
  std::string_view part;        ///< the aircraft part
  std::string_view store_part;  ///< the store part closest to it
  double distance_m = 0;        ///< minimum distance (0 with penetration)
  bool penetration = false;     ///< the meshes intersect
  Feature feature = Feature::kVertexFace;
  geometry::Vec3 p_store_p = geometry::Vec3::Zero();     ///< closest point on the store, frame p
  geometry::Vec3 p_aircraft_p = geometry::Vec3::Zero();  ///< closest point on the part, frame p
  geometry::Vec3 q_store_s = geometry::Vec3::Zero();     ///< the store's point in frame s
  /// Unit contact normal from the part to the store ((p_store - p_aircraft) / d); with
  /// penetration, the part triangle's face normal (the sign is then arbitrary).
  geometry::Vec3 normal_p = geometry::Vec3::UnitZ();
  std::int32_t store_triangle = -1, aircraft_triangle = -1;  ///< indices in their STL files
  double u_distance_m = 0;  ///< first-order standard uncertainty of distance_m
  /// The lower bound b of the minimum distance with sum over distinct candidate features g of
  /// Phi((b - d_g) / u_g) = Phi(-2): d - 2u for one feature, lower where the closest feature can
  /// switch (docs/clearance.md, "Feature switch").
  double lower_bound_m = 0;
  int candidate_pairs = 1;  ///< triangle pairs near enough to be considered
  int features = 1;         ///< distinct features among them (the terms of the sum)
};

/// Bodies with their trees. Store parts in frame s, aircraft parts in frame p.
class ClearanceModel {
 public:
  explicit ClearanceModel(std::vector<Body> bodies);
  /// read_geometry + load_body for each body (T_p_w for aircraft-frame bodies).
  static ClearanceModel load(const std::string& geometry_path,
                             const std::optional<geometry::Transform>& T_p_w = std::nullopt);
  /// The same with every file's bytes through `read` (the geometry file first, then each STL
  /// at the path the geometry resolves): storetrack-host reads from disk and records what it
  /// read, storetrack-post reads the recording's copies.
  static ClearanceModel load(const std::string& geometry_path, const GeometryFileReader& read,
                             const std::optional<geometry::Transform>& T_p_w = std::nullopt);

  /// One entry per aircraft part, in file order. cov_T_p_s over the left perturbation of T_p_s.
  /// A covariance that is not finite gives NaN uncertainties and bounds (never a throw).
  std::vector<PartClearance> evaluate(const geometry::Transform& T_p_s,
                                      const geometry::Mat6& cov_T_p_s);
  /// The same into `out` (resized to aircraft_parts(); no allocation once it has that size).
  void evaluate(const geometry::Transform& T_p_s, const geometry::Mat6& cov_T_p_s,
                std::vector<PartClearance>& out);

  std::size_t store_parts() const { return store_.size(); }
  std::size_t aircraft_parts() const { return aircraft_.size(); }
  std::string_view aircraft_part_name(std::size_t i) const { return aircraft_[i].name; }

 private:
  struct Part {
    std::string name;
    MeshBvh tree;
  };
  /// The covariance's bounds for the feature-switch reach (LeverArmReach without its base).
  struct CovarianceBounds {
    double lambda_max, u_rotation_rad, u_translation_m;
  };
  PartClearance evaluate_part(std::size_t aircraft_part, const geometry::Transform& T_p_s,
                              const geometry::Mat6& cov, const CovarianceBounds& bounds);

  std::vector<Part> store_;
  std::vector<Part> aircraft_;
  struct Candidate {
    double distance, u;
    geometry::Vec6 J;
  };
  // Scratch of the feature-switch pass, kept between samples (no allocation once warm).
  std::vector<MeshPair> pairs_;
  std::vector<Candidate> candidates_;
  std::vector<Candidate> features_;
  // The last sample's closest pair per (aircraft part, store part): the next descent's warm
  // start (a continuous trajectory keeps it near the minimum).
  std::vector<TreePair> previous_;
};

}  // namespace storetrack::clearance
