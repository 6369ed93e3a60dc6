#include "product_csv.hpp"

#include <cmath>
#include <string>

namespace storetrack::post {

bool write_product_csv(std::FILE* f, std::span<const smooth::ProductSample> samples,
                       const smooth::ReleaseTime& release) {
  std::string header = "exposure_mid_tai_ns,t_since_t0_s,u_t0_s,segment,measured,accel_step";
  for (const char* part : {"", "u_", "U_", "u_noise_", "u_shared_"})
    for (const char* n : smooth::kProductNames)
      header += std::string(",") + part + n;
  header += "\n";
  if (std::fputs(header.c_str(), f) < 0) return false;
  const double u_t0 = release.detected ? release.u_t0_s : std::nan("");
  for (const smooth::ProductSample& p : samples) {
    if (std::fprintf(f, "%lld,%.9f,%.3g,%d,%d,%d", static_cast<long long>(p.t_ns), p.t_since_t0_s,
                     u_t0, p.segment, p.measured ? 1 : 0, p.step ? 1 : 0) < 0)
      return false;
    for (const double v : p.value)
      if (std::fprintf(f, ",%.9g", v) < 0) return false;
    const smooth::ProductVector u = p.u();
    for (const smooth::ProductVector& part :
         {u, smooth::ProductVector(2 * u), p.u_noise, p.u_shared})
      for (const double v : part)
        if (std::fprintf(f, ",%.4g", v) < 0) return false;
    if (std::fputc('\n', f) == EOF) return false;
  }
  return true;
}

}  // namespace storetrack::post
