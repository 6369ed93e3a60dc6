// Playing a schedule: edges in order, never early, widths honoured, lines left deasserted; the
// gpio-sim backend writes the sysfs pull attributes (checked on a stand-in directory).
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "storetrack/time/time.hpp"
#include "storetrack/trigger_emu/line_driver.hpp"
#include "storetrack/trigger_emu/player.hpp"

namespace te = storetrack::trigger_emu;

namespace {

class RecordingDriver final : public te::LineDriver {
 public:
  struct Edge {
    int level;
    std::int64_t t;
  };
  int set(int level) override {
    edges.push_back({level, storetrack::time::monotonic_now_ns()});
    return fail_after-- == 0 ? -EIO : 0;
  }
  std::vector<Edge> edges;
  int fail_after = -1;
};

// A sysfs attribute takes each write whole; the regular file standing in for it keeps the tail
// of a longer earlier value ("pull-down" overwritten by "pull-up" reads "pull-upwn").
std::string read_file(const std::filesystem::path& p) {
  std::ifstream in(p);
  std::string s;
  std::getline(in, s);
  return s.rfind("pull-up", 0) == 0 ? "pull-up" : s;
}

}  // namespace

TEST(TriggerPlayer, PlaysEveryEdgeInOrderAndNeverEarly) {
  te::ScheduleConfig c;
  c.rate_hz = 500.0;
  c.pulse_width_ns = 300'000;
  c.count = 40;
  c.faults = {{te::FaultKind::kMissing, 5, 1, 0}, {te::FaultKind::kBurst, 10, 2, 700'000}};
  const auto schedule = te::make_schedule(c);
  RecordingDriver driver;
  std::atomic<bool> stop{false};
  const std::int64_t start = storetrack::time::monotonic_now_ns() + 2'000'000;
  const te::PlayResult r = te::play(driver, schedule, start, stop);
  EXPECT_EQ(r.error, 0);
  EXPECT_FALSE(r.interrupted);
  ASSERT_EQ(r.log.size(), schedule.size());
  const int sent = c.count - 1 + 2;
  ASSERT_EQ(static_cast<int>(driver.edges.size()), 2 * sent + 1);  // + final deassert
  EXPECT_EQ(driver.edges.back().level, 0);
  for (const auto& s : r.log) {
    if (!s.pulse.sent()) {
      EXPECT_EQ(s.rise_mono_ns, 0);
      continue;
    }
    EXPECT_EQ(s.planned_rise_mono_ns, start + s.pulse.rise_offset_ns);
    EXPECT_GE(s.rise_mono_ns, s.planned_rise_mono_ns);
    EXPECT_GE(s.fall_mono_ns - s.rise_mono_ns, s.pulse.width_ns);
  }
  const te::Lateness l = te::lateness(r.log);
  EXPECT_EQ(l.sent, sent);
  EXPECT_GE(l.mean_ns, 0.0);
}

TEST(TriggerPlayer, StopsAtTheFirstWriteErrorAndAtStop) {
  te::ScheduleConfig c;
  c.rate_hz = 1000.0;
  c.pulse_width_ns = 100'000;
  c.count = 10;
  const auto schedule = te::make_schedule(c);
  RecordingDriver driver;
  driver.fail_after = 3;  // 4th write fails: the 2nd pulse's falling edge
  std::atomic<bool> stop{false};
  te::PlayResult r = te::play(driver, schedule, storetrack::time::monotonic_now_ns(), stop);
  EXPECT_EQ(r.error, -EIO);
  EXPECT_EQ(r.log.size(), 1u);

  RecordingDriver idle;
  stop = true;
  r = te::play(idle, schedule, storetrack::time::monotonic_now_ns() + 1'000'000'000, stop);
  EXPECT_TRUE(r.interrupted);
  EXPECT_TRUE(r.log.empty());
  ASSERT_EQ(idle.edges.size(), 1u);
  EXPECT_EQ(idle.edges[0].level, 0);
}

TEST(SimPullLineDriver, WritesPullAttributesWithPolarity) {
  char tmpl[] = "/tmp/trigger_emu_sysfsXXXXXX";
  ASSERT_NE(mkdtemp(tmpl), nullptr);
  const std::filesystem::path dir(tmpl);
  for (int i : {0, 3}) {
    std::filesystem::create_directories(dir / ("sim_gpio" + std::to_string(i)));
    std::ofstream(dir / ("sim_gpio" + std::to_string(i)) / "pull") << "pull-down";
  }
  {
    te::SimPullLineDriver d(dir.string(), {0, 3}, false);
    ASSERT_EQ(d.set(1), 0);
    EXPECT_EQ(read_file(dir / "sim_gpio0/pull"), "pull-up");
    EXPECT_EQ(read_file(dir / "sim_gpio3/pull"), "pull-up");
    ASSERT_EQ(d.set(0), 0);
    EXPECT_EQ(read_file(dir / "sim_gpio3/pull"), "pull-down");
  }
  {
    te::SimPullLineDriver d(dir.string(), {0}, true);  // active low: idle is electrically high
    EXPECT_EQ(read_file(dir / "sim_gpio0/pull"), "pull-up");
    ASSERT_EQ(d.set(1), 0);
    EXPECT_EQ(read_file(dir / "sim_gpio0/pull"), "pull-down");
  }
  EXPECT_THROW(te::SimPullLineDriver(dir.string(), {7}, false), std::runtime_error);
  EXPECT_EQ(te::SimPullLineDriver::sysfs_dir_for_chip("/dev/gpiochip2"),
            "/sys/bus/gpio/devices/gpiochip2");
  std::filesystem::remove_all(dir);
}
