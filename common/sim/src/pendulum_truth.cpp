#include "storetrack/sim/pendulum_truth.hpp"

#include <cmath>
#include <fstream>
#include <stdexcept>

#include <nlohmann/json.hpp>

namespace storetrack::sim {

PendulumTruth pendulum_truth(const Simulator& sim) {
  const Scenario& sc = sim.scenario();
  if (sc.kind != ScenarioKind::kPendulum)
    throw std::invalid_argument("pendulum_truth: scenario '" + sc.name + "' is not a pendulum");
  PendulumTruth t;
  t.motion = sc.pendulum_motion;
  const PendulumMotion& m = t.motion;
  t.equivalent_length_m = m.l2_m * m.l2_m / m.l1_m;
  t.damping_per_inertia_1_s = m.damping_n_m_s / (m.mass_kg * m.l2_m * m.l2_m);
  t.release_tai_ns = sc.start_tai_ns + std::llround(m.release_time_s * 1e9);
  // The cameras ride on the pylon: the host's world is T_w_p0 T_p (vibration cancels).
  const geometry::Transform T_w0_pivot = sc.T_w_p * sim.pendulum().T_p_pivot();
  t.pivot_w = T_w0_pivot.translation();
  t.normal_w = T_w0_pivot.linear().col(2);
  for (const survey::SurveyedMark& mark : sc.pendulum.marks) {
    const geometry::Vec3& b = mark.p_body;
    t.marks.push_back({mark.id, std::hypot(b.x(), b.y()), std::atan2(b.y(), b.x()), b.z()});
  }
  for (int k = 0; k < sim.num_exposures(); ++k) {
    const ExposureTruth e = sim.truth(k);
    const double s = sim.seconds_since_start(e.reference_tai_ns);
    t.exposures.push_back({e.trigger_seq, e.reference_tai_ns, sim.pendulum().theta(s),
                           sim.pendulum().theta_dot(s), sc.T_w_p * e.T_p_s});
  }
  return t;
}

void write_pendulum_truth_json(const Simulator& sim, const std::string& path) {
  const PendulumTruth t = pendulum_truth(sim);
  const PendulumMotion& m = t.motion;
  const auto vec = [](const geometry::Vec3& v) { return nlohmann::json{v.x(), v.y(), v.z()}; };
  nlohmann::json doc = {
      {"format", "storetrack-pendulum-truth"},
      {"version", 1},
      {"frame", "w0 (the host's world frame)"},
      {"model", "m l2^2 theta'' + beta theta' + m g l1 sin(theta) = 0, theta = 0 hanging down"},
      {"l1_m", m.l1_m},
      {"l2_m", m.l2_m},
      {"mass_kg", m.mass_kg},
      {"damping_n_m_s", m.damping_n_m_s},
      {"g_m_s2", m.g_m_s2},
      {"equivalent_length_m", t.equivalent_length_m},
      {"damping_per_inertia_1_s", t.damping_per_inertia_1_s},
      {"theta0_rad", m.theta0_rad},
      {"theta0_deg", m.theta0_rad * 180 / M_PI},
      {"theta_dot0_rad_s", m.theta_dot0_rad_s},
      {"release_time_s", m.release_time_s},
      {"release_tai_ns", t.release_tai_ns},
      {"pivot_w_m", vec(t.pivot_w)},
      {"normal_w", vec(t.normal_w)}};
  for (const PendulumMarkTruth& k : t.marks)
    doc["marks"].push_back({{"mark_id", k.id},
                            {"radius_m", k.radius_m},
                            {"angle_rad", k.angle_rad},
                            {"offset_m", k.offset_m}});
  for (const PendulumExposureTruth& e : t.exposures) {
    const geometry::Vec3 rv = geometry::rotvec_from_rotation(e.T_w0_b.linear());
    doc["exposures"].push_back({{"trigger_seq", e.trigger_seq},
                                {"reference_tai_ns", e.reference_tai_ns},
                                {"theta_rad", e.theta_rad},
                                {"theta_dot_rad_s", e.theta_dot_rad_s},
                                {"T_w0_b_translation_m", vec(e.T_w0_b.translation())},
                                {"T_w0_b_rotvec_rad", vec(rv)}});
  }
  std::ofstream f(path);
  f << doc.dump(1) << "\n";
  if (!f) throw std::runtime_error(path + ": cannot write the pendulum truth");
}

}  // namespace storetrack::sim
