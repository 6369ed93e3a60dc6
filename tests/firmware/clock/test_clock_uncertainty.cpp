// The clock's time uncertainty (clock_uncertainty.hpp) against closed forms: the window's RMS
// against a direct sum, its ring over more offsets than it holds, the holdover growth
// sqrt(u^2 + (y t)^2), and which polls of the lock state machine bring a new measurement (a Sync
// not seen before) and which hold the figure without growth.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "storetrack/clock/clock_uncertainty.hpp"
#include "storetrack/clock/lock_state.hpp"

namespace storetrack::clock {
namespace {

constexpr std::int64_t kS = 1'000'000'000;

double rms(const std::vector<std::int64_t>& xs) {
  double sum = 0;
  for (std::int64_t x : xs)
    sum += static_cast<double>(x) * static_cast<double>(x);
  return std::sqrt(sum / static_cast<double>(xs.size()));
}

TEST(ClockUncertainty, WindowIsTheRmsOfItsLastOffsets) {
  OffsetWindow w(4);
  EXPECT_EQ(w.rms_ns(), 0.0);
  const std::vector<std::int64_t> offsets = {300, -400, 1200, -50, 700, -2500, 10};
  std::vector<std::int64_t> seen;
  for (std::int64_t x : offsets) {
    w.add(x);
    seen.push_back(x);
    const std::vector<std::int64_t> last(seen.end() - std::min<std::ptrdiff_t>(4, seen.size()),
                                         seen.end());
    EXPECT_NEAR(w.rms_ns(), rms(last), 1e-9 * rms(last)) << "after " << seen.size();
    EXPECT_EQ(w.count(), static_cast<int>(last.size()));
  }
}

TEST(ClockUncertainty, WindowSizeIsClampedToItsStorage) {
  OffsetWindow big(1000), none(0);
  for (int i = 0; i < 200; ++i) {
    big.add(i);
    none.add(i);
  }
  EXPECT_EQ(big.count(), kMaxOffsetWindow);
  EXPECT_EQ(none.count(), 1);
  EXPECT_EQ(none.rms_ns(), 199.0);
}

TEST(ClockUncertainty, HeldFigureDoesNotGrowAndAnUnsteeredOneGrowsLinearly) {
  ClockFigure f;
  EXPECT_EQ(f.sigma_ns_at(5 * kS, 1000), std::numeric_limits<double>::infinity());  // never
  f.rms_ns = 800;
  f.measured_at_ns = 100 * kS;
  f.holding = true;
  EXPECT_EQ(f.sigma_ns_at(130 * kS, 1000), 800.0);
  f.holding = false;  // holdover: 1 ppm for 3 s is 3000 ns, in quadrature with 800 ns
  EXPECT_NEAR(f.sigma_ns_at(103 * kS, 1000), std::hypot(800.0, 3000.0), 1e-9);
  EXPECT_NEAR(f.sigma_ns_at(110 * kS, 50), std::hypot(800.0, 500.0), 1e-9);
  EXPECT_EQ(f.sigma_ns_at(99 * kS, 1000), 800.0);  // an exposure stamped before the poll
}

PtpPoll poll(std::int64_t offset_ns, std::int64_t ingress_ns, PortState port = PortState::kSlave) {
  PtpPoll p;
  p.answered = true;
  p.port_state = port;
  p.gm_present = true;
  p.master_offset_ns = offset_ns;
  p.ingress_time_ns = ingress_ns;
  return p;
}

TEST(ClockUncertainty, OnlyANewSyncIsANewMeasurementAndOnlyAFreshOneHolds) {
  LockThresholds t;
  t.offset_max_age_ns = 2 * kS;
  LockStateMachine m(t);
  m.update(poll(100, 0), 0);  // before the first Sync ptp4l reports offset 0: no measurement
  EXPECT_FALSE(m.new_measurement());
  m.update(poll(100, 7 * kS), 1 * kS);
  EXPECT_TRUE(m.new_measurement());
  EXPECT_TRUE(m.holding());
  m.update(poll(100, 7 * kS), 2 * kS);  // the same Sync again: not new, still fresh
  EXPECT_FALSE(m.new_measurement());
  EXPECT_TRUE(m.holding());
  m.update(poll(100, 7 * kS), 4 * kS);  // 3 s old: stale, the clock runs on its own
  EXPECT_FALSE(m.new_measurement());
  EXPECT_FALSE(m.holding());
  m.update(poll(100, 9 * kS, PortState::kListening), 5 * kS);  // master lost
  EXPECT_FALSE(m.new_measurement());
  EXPECT_FALSE(m.holding());
}

}  // namespace
}  // namespace storetrack::clock
