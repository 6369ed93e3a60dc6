#include "smoothed_csv.hpp"

#include <array>
#include <cmath>
#include <string>

#include "storetrack/pose/body_pose.hpp"

namespace storetrack::post {

namespace {

using smooth::SmoothedState;
using smooth::StateMatrix;

// Rows of the state for x..z, (yaw, pitch, roll: rotation, mapped), v, a, omega, alpha.
constexpr std::array<int, 6> kBlocks = {smooth::kPosition,    smooth::kAttitude,
                                        smooth::kVelocity,    smooth::kAcceleration,
                                        smooth::kAngularRate, smooth::kAngularAccel};

}  // namespace

const std::array<const char*, kSmoothedOutputs> kSmoothedNames = {
    "x_m",      "y_m",      "z_m",      "yaw_rad",       "pitch_rad",     "roll_rad",
    "vx_m_s",   "vy_m_s",   "vz_m_s",   "ax_m_s2",       "ay_m_s2",       "az_m_s2",
    "wx_rad_s", "wy_rad_s", "wz_rad_s", "alphax_rad_s2", "alphay_rad_s2", "alphaz_rad_s2"};

void smoothed_outputs(const SmoothedState& s, std::array<double, kSmoothedOutputs>& value,
                      SmoothedOutputMap& M) {
  M.setZero();
  const std::array<geometry::Vec3, 6> vectors = {
      s.T_p_s.translation(), geometry::ypr_from_rotation(s.T_p_s.linear()),
      s.velocity_p,          s.accel_p,
      s.angular_rate_p,      s.angular_accel_p};
  for (std::size_t b = 0; b < 6; ++b) {
    for (std::size_t a = 0; a < 3; ++a)
      value[3 * b + a] = vectors[b](static_cast<Eigen::Index>(a));
    const auto row = static_cast<Eigen::Index>(3 * b);
    if (b == 1)  // yaw, pitch, roll from the left rotation perturbation
      M.block<3, 3>(row, kBlocks[b]) = pose::ypr_jacobian(s.T_p_s.linear());
    else
      M.block<3, 3>(row, kBlocks[b]).setIdentity();
  }
}

bool write_smoothed_csv(std::FILE* f, std::span<const SmoothedState> states) {
  std::string header = "exposure_mid_tai_ns,segment,measured,accel_step";
  for (const char* n : kSmoothedNames)
    header += std::string(",") + n;
  for (const char* part : {"u_", "u_noise_", "u_shared_"})
    for (const char* n : kSmoothedNames)
      header += std::string(",") + part + n;
  header += "\n";
  if (std::fputs(header.c_str(), f) < 0) return false;
  std::array<double, kSmoothedOutputs> value{};
  SmoothedOutputMap M;
  for (const SmoothedState& s : states) {
    smoothed_outputs(s, value, M);
    const StateMatrix parts[3] = {s.cov(), s.cov_noise, s.cov_shared()};
    if (std::fprintf(f, "%lld,%d,%d,%d", static_cast<long long>(s.t_ns), s.segment,
                     s.measured ? 1 : 0, s.step ? 1 : 0) < 0)
      return false;
    for (const double v : value)
      if (std::fprintf(f, ",%.9g", v) < 0) return false;
    for (const StateMatrix& C : parts) {
      const Eigen::Matrix<double, 18, 1> var = (M * C * M.transpose()).diagonal();
      for (int i = 0; i < 18; ++i)
        if (std::fprintf(f, ",%.4g", std::sqrt(std::max(var(i), 0.0))) < 0) return false;
    }
    if (std::fputc('\n', f) == EOF) return false;
  }
  return true;
}

}  // namespace storetrack::post
