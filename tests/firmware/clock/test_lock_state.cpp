// The lock state machine over scripted polls: lock after N polls within the threshold, loss of
// the master to HOLDOVER and, after the holdover time, FREE_RUNNING; recovery; ptp4l silent
// from the start; the wire values of the states and of the offset.
#include <gtest/gtest.h>

#include "storetrack/clock/lock_state.hpp"

namespace storetrack::clock {
namespace {

using time::ClockState;
constexpr std::int64_t kS = 1'000'000'000;

/// A poll of ptp4l with a fresh measurement (each call a new Sync's ingress time).
PtpPoll slave(std::int64_t offset_ns, PortState port = PortState::kSlave) {
  static std::int64_t ingress_time_ns = 1'796'236'652'230'701'337;
  PtpPoll p;
  p.ingress_time_ns = ingress_time_ns += 125'000'000;
  p.answered = true;
  p.port_state = port;
  p.gm_present = true;
  p.master_offset_ns = offset_ns;
  return p;
}

PtpPoll master_lost() {
  PtpPoll p = slave(720, PortState::kListening);  // what ptp4l says after announce timeout
  return p;
}

PtpPoll silent() {
  return PtpPoll{};  // ptp4l did not answer
}

LockThresholds thresholds() {
  LockThresholds t;
  t.lock_threshold_ns = 1000;
  t.lock_polls = 3;
  t.holdover_ns = 10 * kS;
  return t;
}

TEST(LockState, WireValuesAreTheSchemas) {
  // common/msg/schema/mark_observations.yaml clock_state: 0 free-running .. 3 holdover.
  EXPECT_EQ(static_cast<int>(ClockState::kFreeRunning), 0);
  EXPECT_EQ(static_cast<int>(ClockState::kLocking), 1);
  EXPECT_EQ(static_cast<int>(ClockState::kLocked), 2);
  EXPECT_EQ(static_cast<int>(ClockState::kHoldover), 3);
}

TEST(LockState, StartsFreeRunningAndStaysSoWhilePtp4lIsSilent) {
  LockStateMachine m(thresholds());
  EXPECT_EQ(m.state(), ClockState::kFreeRunning);
  for (int i = 0; i < 20; ++i)
    EXPECT_EQ(m.update(silent(), i * kS), ClockState::kFreeRunning);
  EXPECT_EQ(m.offset_ns(), kOffsetUnknown);
}

TEST(LockState, LocksAfterNConsecutivePollsWithin) {
  LockStateMachine m(thresholds());
  EXPECT_EQ(m.update(slave(5000, PortState::kUncalibrated), 0), ClockState::kLocking);
  EXPECT_EQ(m.offset_ns(), 5000);
  EXPECT_EQ(m.update(slave(900), 1 * kS), ClockState::kLocking);
  EXPECT_EQ(m.update(slave(-1000), 2 * kS), ClockState::kLocking);  // the threshold counts
  EXPECT_EQ(m.update(slave(1001), 3 * kS), ClockState::kLocking);   // one over: count restarts
  EXPECT_EQ(m.update(slave(10), 4 * kS), ClockState::kLocking);
  EXPECT_EQ(m.update(slave(-10), 5 * kS), ClockState::kLocking);
  EXPECT_EQ(m.update(slave(0), 6 * kS), ClockState::kLocked);
  EXPECT_EQ(m.offset_ns(), 0);
  EXPECT_EQ(m.update(slave(-999), 7 * kS), ClockState::kLocked);
  EXPECT_EQ(m.offset_ns(), -999);
}

TEST(LockState, AnOffsetOutsideTheThresholdLeavesLockedAtOnce) {
  LockStateMachine m(thresholds());
  for (int i = 0; i < 3; ++i)
    m.update(slave(0), i * kS);
  ASSERT_EQ(m.state(), ClockState::kLocked);
  EXPECT_EQ(m.update(slave(50'000), 3 * kS), ClockState::kLocking);
}

TEST(LockState, UncalibratedIsNotLockedUnlessMeasureOnly) {
  LockStateMachine strict(thresholds());
  LockThresholds t = thresholds();
  t.measure_only = true;
  LockStateMachine measuring(t);
  for (int i = 0; i < 5; ++i) {
    strict.update(slave(100, PortState::kUncalibrated), i * kS);
    measuring.update(slave(100, PortState::kUncalibrated), i * kS);
  }
  EXPECT_EQ(strict.state(), ClockState::kLocking);  // ptp4l's servo has not locked
  EXPECT_EQ(measuring.state(), ClockState::kLocked);
}

TEST(LockState, LossOfMasterGoesToHoldoverThenFreeRunning) {
  LockStateMachine m(thresholds());
  for (int i = 0; i < 3; ++i)
    m.update(slave(0), i * kS);
  ASSERT_EQ(m.state(), ClockState::kLocked);
  const std::int64_t t_loss = 10 * kS;
  EXPECT_EQ(m.update(master_lost(), t_loss), ClockState::kHoldover);
  EXPECT_EQ(m.offset_ns(), kOffsetUnknown);  // gmPresent still 1, but no master: not an offset
  EXPECT_EQ(m.update(silent(), t_loss + 5 * kS), ClockState::kHoldover);
  EXPECT_EQ(m.update(master_lost(), t_loss + 10 * kS - 1), ClockState::kHoldover);
  EXPECT_EQ(m.update(master_lost(), t_loss + 10 * kS), ClockState::kFreeRunning);
  EXPECT_EQ(m.update(master_lost(), t_loss + 11 * kS), ClockState::kFreeRunning);
}

TEST(LockState, EachWayOfLosingTheMasterCounts) {
  PtpPoll no_gm = slave(0);
  no_gm.gm_present = false;
  PtpPoll master_port = slave(0, PortState::kMaster);
  PtpPoll faulty = slave(0, PortState::kFaulty);
  for (const PtpPoll& lost : {no_gm, master_port, faulty, silent()}) {
    LockStateMachine m(thresholds());
    for (int i = 0; i < 3; ++i)
      m.update(slave(0), i * kS);
    EXPECT_EQ(m.update(lost, 3 * kS), ClockState::kHoldover)
        << to_string(lost.port_state) << " gm_present " << lost.gm_present;
  }
}

TEST(LockState, RecoveryFromHoldoverRelocksAfterNPolls) {
  LockStateMachine m(thresholds());
  for (int i = 0; i < 3; ++i)
    m.update(slave(0), i * kS);
  m.update(master_lost(), 3 * kS);
  ASSERT_EQ(m.state(), ClockState::kHoldover);
  EXPECT_EQ(m.update(slave(20'000, PortState::kUncalibrated), 4 * kS), ClockState::kLocking);
  EXPECT_EQ(m.update(slave(10), 5 * kS), ClockState::kLocking);
  EXPECT_EQ(m.update(slave(10), 6 * kS), ClockState::kLocking);
  EXPECT_EQ(m.update(slave(10), 7 * kS), ClockState::kLocked);
  // A second loss starts a fresh holdover time.
  EXPECT_EQ(m.update(silent(), 100 * kS), ClockState::kHoldover);
  EXPECT_EQ(m.update(silent(), 109 * kS), ClockState::kHoldover);
  EXPECT_EQ(m.update(silent(), 110 * kS), ClockState::kFreeRunning);
}

TEST(LockState, LossWhileLockingIsFreeRunningNotHoldover) {
  LockStateMachine m(thresholds());
  m.update(slave(0), 0);
  ASSERT_EQ(m.state(), ClockState::kLocking);
  EXPECT_EQ(m.update(master_lost(), kS), ClockState::kFreeRunning);
}

TEST(LockState, ZeroHoldoverGoesStraightToFreeRunning) {
  LockThresholds t = thresholds();
  t.holdover_ns = 0;
  LockStateMachine m(t);
  for (int i = 0; i < 3; ++i)
    m.update(slave(0), i * kS);
  EXPECT_EQ(m.update(silent(), 3 * kS), ClockState::kFreeRunning);
}

TEST(LockState, TraceabilityWhenRequired) {
  LockThresholds t = thresholds();
  t.require_time_traceable = true;
  LockStateMachine m(t);
  for (int i = 0; i < 5; ++i)
    m.update(slave(0), i * kS);
  EXPECT_EQ(m.state(), ClockState::kFreeRunning);  // a grandmaster not traceable to TAI
  PtpPoll traceable = slave(0);
  traceable.time_traceable = true;
  for (int i = 5; i < 8; ++i)
    m.update(traceable, i * kS);
  EXPECT_EQ(m.state(), ClockState::kLocked);
}

TEST(LockState, NoMeasurementYetIsNotAnOffsetOfZero) {
  // Before its first Sync ptp4l reports master_offset 0 with ingress_time 0.
  LockStateMachine m(thresholds());
  PtpPoll first = slave(0, PortState::kUncalibrated);
  first.ingress_time_ns = 0;
  for (int i = 0; i < 5; ++i)
    EXPECT_EQ(m.update(first, i * kS), ClockState::kLocking);
}

TEST(LockState, AStaleOffsetLeavesLocked) {
  // The master still announces (port SLAVE) but sends no Sync: ingress_time stops changing.
  LockThresholds t = thresholds();
  t.offset_max_age_ns = 3 * kS;
  LockStateMachine m(t);
  PtpPoll p;
  for (int i = 0; i < 3; ++i)
    m.update(p = slave(0), i * kS);
  ASSERT_EQ(m.state(), ClockState::kLocked);
  EXPECT_EQ(m.update(p, 3 * kS), ClockState::kLocked);  // 1 s without a new Sync: fine
  EXPECT_EQ(m.update(p, 4 * kS), ClockState::kLocked);
  EXPECT_EQ(m.update(p, 5 * kS), ClockState::kLocking);  // 3 s: stale
  EXPECT_EQ(m.update(slave(0), 6 * kS), ClockState::kLocking);
  EXPECT_EQ(m.update(slave(0), 7 * kS), ClockState::kLocking);
  EXPECT_EQ(m.update(slave(0), 8 * kS), ClockState::kLocked);
}

TEST(LockState, OffsetSaturatesOneAboveTheUnknownValue) {
  EXPECT_EQ(saturate_offset_ns(0), 0);
  EXPECT_EQ(saturate_offset_ns(-5), -5);
  EXPECT_EQ(saturate_offset_ns(std::int64_t{1} << 40), INT32_MAX);
  EXPECT_EQ(saturate_offset_ns(-(std::int64_t{1} << 40)), INT32_MIN + 1);
  EXPECT_EQ(saturate_offset_ns(INT32_MIN), INT32_MIN + 1);
  EXPECT_EQ(saturate_offset_ns(INT64_MIN), INT32_MIN + 1);
  LockStateMachine m(thresholds());
  m.update(slave(INT64_MIN), 0);  // no overflow in the threshold comparison either
  EXPECT_EQ(m.state(), ClockState::kLocking);
  EXPECT_EQ(m.offset_ns(), INT32_MIN + 1);
}

}  // namespace
}  // namespace storetrack::clock
