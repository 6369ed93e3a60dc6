#include "storetrack/clock/clock_uncertainty.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace storetrack::clock {

double ClockFigure::sigma_ns_at(time::MonotonicNs t_ns, double drift_ppb) const {
  if (measured_at_ns == 0) return std::numeric_limits<double>::infinity();
  if (holding) return rms_ns;
  // A poll's time may precede an exposure stamped a moment earlier: no negative growth.
  const double since_ns =
      static_cast<double>(std::max<time::MonotonicNs>(0, t_ns - measured_at_ns));
  return std::hypot(rms_ns, drift_ppb * 1e-9 * since_ns);
}

OffsetWindow::OffsetWindow(int size) : size_(std::clamp(size, 1, kMaxOffsetWindow)) {}

void OffsetWindow::add(std::int64_t offset_ns) {
  const auto x = static_cast<double>(offset_ns);
  squares_[static_cast<std::size_t>(next_)] = x * x;
  next_ = (next_ + 1) % size_;
  count_ = std::min(count_ + 1, size_);
}

double OffsetWindow::rms_ns() const {
  if (count_ == 0) return 0;
  double sum = 0;
  for (int i = 0; i < count_; ++i)
    sum += squares_[static_cast<std::size_t>(i)];
  return std::sqrt(sum / count_);
}

}  // namespace storetrack::clock
