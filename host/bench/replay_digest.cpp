// storetrack-host-replay-digest: every number the processor produces over the store-separation
// scenario (the data of storetrack-host-bench), printed exactly (hex floats), so that a speed
// change can be shown to leave the results bit-identical: run it before and after and diff the
// outputs (docs/performance.md, "Host processing"). Both paths: with the matcher (as the host
// runs) and with the simulator's truth ids.
//
//     storetrack-host-replay-digest > before.txt   # ... change, rebuild ...
//     storetrack-host-replay-digest > after.txt && cmp before.txt after.txt
#include <cstdio>
#include <string>

#include <Eigen/Core>

#include "simulated_exposures.hpp"

namespace {

using namespace storetrack;

template <typename Derived>
void print(const char* name, const Eigen::DenseBase<Derived>& m) {
  std::printf("%s", name);
  for (Eigen::Index r = 0; r < m.rows(); ++r)
    for (Eigen::Index c = 0; c < m.cols(); ++c)
      std::printf(" %a", m(r, c));
  std::printf("\n");
}

void print_pose(const char* name, const pipeline::PoseResult& p) {
  std::printf("%s valid %d marks %d chi2 %a\n", name, p.valid ? 1 : 0, p.marks_used, p.chi2);
  print("  T", p.T.matrix());
  print("  cov", p.cov);
  for (const geometry::Mat6& c : p.cov_by_source)
    print("  cov_source", c);
  print("  loadings", p.loadings);
  print("  survey_loadings", p.survey_loadings);
}

void print_sample(const msg::FtiSample& s) {
  std::printf("sample %lld %u %u %u %u %u %u\n", static_cast<long long>(s.exposure_mid_tai_ns),
              s.trigger_seq, s.store_id, s.cameras_used, s.marks_used, s.pylon_marks_used,
              s.status);
  const float values[] = {s.x_m,
                          s.y_m,
                          s.z_m,
                          s.yaw_rad,
                          s.pitch_rad,
                          s.roll_rad,
                          s.u_x_m,
                          s.u_y_m,
                          s.u_z_m,
                          s.u_yaw_rad,
                          s.u_pitch_rad,
                          s.u_roll_rad,
                          s.u_budget_centroid_m,
                          s.u_budget_intrinsic_m,
                          s.u_budget_extrinsic_m,
                          s.u_budget_sync_m,
                          s.u_budget_process_m,
                          s.coverage_factor};
  std::printf("  fields");
  for (float v : values)
    std::printf(" %a", static_cast<double>(v));
  for (float v : s.correlation)
    std::printf(" %a", static_cast<double>(v));
  std::printf("\n");
}

void print_result(const pipeline::ExposureResult& r) {
  print_sample(r.sample);
  for (const pipeline::MarkResult& m : r.marks) {
    std::printf("mark %d %c excluded %d chi2 %a\n", m.id, m.body, m.excluded ? 1 : 0, m.chi2);
    print("  p_w", m.p_w);
    print("  cov_w", m.cov_w);
    for (const geometry::Mat3& c : m.cov_by_source)
      print("  cov_source", c);
    print("  loadings", m.loadings);
    for (const auto& o : m.observations) {
      std::printf("  obs %d %d %a", o.camera_id, o.mark_index, o.sigma_px);
      print("", o.residual_px);
    }
  }
  print_pose("T_w_p", r.T_w_p);
  print_pose("T_w_s", r.T_w_s);
  print_pose("T_p_s", r.T_p_s);
  print("xyz_ypr", r.xyz_ypr);
  print("cov_xyz_ypr", r.cov_xyz_ypr);
  for (const geometry::Mat6& c : r.cov_xyz_ypr_by_source)
    print("cov_xyz_ypr_source", c);
}

}  // namespace

int main() {
  const bench::SimulatedExposures& d = bench::store_separation();
  for (const bool known_ids : {false, true}) {
    pipeline::ExposureProcessor proc = bench::make_processor(d.sim);
    pipeline::ExposureResult reused;  // the matched path into one result, as a replay loop does
    for (size_t k = 0; k < d.exposures.size(); ++k) {
      std::printf("== %s exposure %zu\n", known_ids ? "known-ids" : "matched", k);
      if (known_ids) {
        print_result(proc.process(d.exposures[k], d.truth_ids[k]));
      } else {
        proc.process(d.exposures[k], reused);
        print_result(reused);
      }
    }
  }
  return 0;
}
