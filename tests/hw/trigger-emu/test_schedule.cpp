// Schedule generation of the trigger emulator: nominal timing, jitter bounds and statistics,
// each fault kind, validation, and the CSV/JSON logs read back.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "storetrack/trigger_emu/schedule.hpp"

namespace te = storetrack::trigger_emu;

namespace {

te::ScheduleConfig base(int count = 50) {
  te::ScheduleConfig c;
  c.rate_hz = 100.0;
  c.pulse_width_ns = 500'000;
  c.count = count;
  return c;
}

int count_kind(const std::vector<te::ScheduledPulse>& s, te::PulseKind k) {
  return static_cast<int>(
      std::count_if(s.begin(), s.end(), [k](const auto& p) { return p.kind == k; }));
}

}  // namespace

TEST(TriggerSchedule, NominalPulsesAreExactlyOnePeriodApart) {
  const te::ScheduleConfig c = base();
  const auto s = te::make_schedule(c);
  ASSERT_EQ(static_cast<int>(s.size()), c.count);
  EXPECT_EQ(te::period_ns(c), 10'000'000);
  for (int i = 0; i < c.count; ++i) {
    EXPECT_EQ(s[i].rise_offset_ns, i * te::period_ns(c));
    EXPECT_EQ(s[i].width_ns, c.pulse_width_ns);
    EXPECT_EQ(s[i].nominal_index, i);
    EXPECT_EQ(s[i].kind, te::PulseKind::kNominal);
  }
}

TEST(TriggerSchedule, NonIntegerPeriodDoesNotDrift) {
  te::ScheduleConfig c = base(3000);
  c.rate_hz = 30.0;  // 33 333 333.3 ns: rounding once, not accumulating per pulse
  const auto s = te::make_schedule(c);
  const double expected_last = (c.count - 1) * std::llround(1e9 / 30.0);
  EXPECT_EQ(s.back().rise_offset_ns, static_cast<std::int64_t>(expected_last));
}

TEST(TriggerSchedule, JitterIsBoundedUniformAndSeeded) {
  te::ScheduleConfig c = base(4000);
  c.jitter_ns = 200'000;
  c.seed = 7;
  const auto s = te::make_schedule(c);
  double sum = 0, sum2 = 0;
  for (const auto& p : s) {
    const double d = static_cast<double>(p.rise_offset_ns - p.nominal_index * te::period_ns(c));
    ASSERT_LE(std::abs(d), c.jitter_ns);
    sum += d;
    sum2 += d * d;
  }
  const double n = static_cast<double>(s.size());
  const double mean = sum / n;
  const double sd = std::sqrt(sum2 / n - mean * mean);
  const double uniform_sd = c.jitter_ns / std::sqrt(3.0);  // U(-a, a): sigma = a / sqrt(3)
  EXPECT_LT(std::abs(mean), 5.0 * uniform_sd / std::sqrt(n));
  EXPECT_NEAR(sd, uniform_sd, 0.05 * uniform_sd);
  EXPECT_EQ(te::make_schedule(c)[123].rise_offset_ns, s[123].rise_offset_ns);
  c.seed = 8;
  EXPECT_NE(te::make_schedule(c)[123].rise_offset_ns, s[123].rise_offset_ns);
}

TEST(TriggerSchedule, MissingPulseIsWithheldButLogged) {
  te::ScheduleConfig c = base();
  c.faults = {{te::FaultKind::kMissing, 10, 1, 0}, {te::FaultKind::kMissing, 11, 1, 0}};
  const auto s = te::make_schedule(c);
  ASSERT_EQ(static_cast<int>(s.size()), c.count);
  EXPECT_EQ(count_kind(s, te::PulseKind::kMissing), 2);
  EXPECT_FALSE(s[10].sent());
  EXPECT_FALSE(s[11].sent());
  EXPECT_TRUE(s[12].sent());
  EXPECT_EQ(s[12].rise_offset_ns, 12 * te::period_ns(c));
}

TEST(TriggerSchedule, FaultsDoNotShiftTheJitterOfLaterPulses) {
  te::ScheduleConfig c = base();
  c.jitter_ns = 100'000;
  const auto clean = te::make_schedule(c);
  c.faults = {{te::FaultKind::kMissing, 5, 1, 0}, {te::FaultKind::kBurst, 7, 3, 0}};
  const auto faulty = te::make_schedule(c);
  EXPECT_EQ(clean.back().rise_offset_ns, faulty.back().rise_offset_ns);
}

TEST(TriggerSchedule, DoublePulseFollowsTheNominalAfterTheGap) {
  te::ScheduleConfig c = base();
  c.faults = {{te::FaultKind::kDouble, 20, 1, 1'500'000}};
  const auto s = te::make_schedule(c);
  ASSERT_EQ(static_cast<int>(s.size()), c.count + 1);
  EXPECT_EQ(s[21].kind, te::PulseKind::kDouble);
  EXPECT_EQ(s[21].nominal_index, 20);
  EXPECT_EQ(s[21].rise_offset_ns - s[20].rise_offset_ns, 1'500'000);
  EXPECT_EQ(s[22].nominal_index, 21);
}

TEST(TriggerSchedule, BurstAddsCountPulsesWithDefaultGapOfTwoWidths) {
  te::ScheduleConfig c = base();
  c.faults = {{te::FaultKind::kBurst, 30, 5, 0}};
  const auto s = te::make_schedule(c);
  ASSERT_EQ(static_cast<int>(s.size()), c.count + 5);
  EXPECT_EQ(count_kind(s, te::PulseKind::kBurst), 5);
  for (int k = 1; k <= 5; ++k) {
    EXPECT_EQ(s[30 + k].rise_offset_ns - s[30].rise_offset_ns, k * 2 * c.pulse_width_ns);
  }
  // time order holds across the whole schedule, and no pulse overlaps the next
  for (std::size_t i = 1; i < s.size(); ++i) {
    EXPECT_GT(s[i].rise_offset_ns, s[i - 1].rise_offset_ns + s[i - 1].width_ns);
  }
}

TEST(TriggerSchedule, InvalidConfigurationsAreRejectedWithAReason) {
  te::ScheduleConfig c = base();
  c.pulse_width_ns = te::period_ns(c);
  EXPECT_THROW(te::validate(c), std::invalid_argument);
  c = base();
  c.rate_hz = 0;
  EXPECT_THROW(te::validate(c), std::invalid_argument);
  c = base();
  c.faults = {{te::FaultKind::kDouble, 3, 1, c.pulse_width_ns}};  // edges would merge
  EXPECT_THROW(te::validate(c), std::invalid_argument);
  c = base();
  c.faults = {{te::FaultKind::kBurst, 3, 50, 0}};  // 50 x 1 ms > 10 ms period
  EXPECT_THROW(te::validate(c), std::invalid_argument);
  c = base();
  c.faults = {{te::FaultKind::kMissing, c.count, 1, 0}};
  EXPECT_THROW(te::validate(c), std::invalid_argument);
  c = base();
  c.faults = {{te::FaultKind::kMissing, 4, 1, 0}, {te::FaultKind::kDouble, 4, 1, 0}};
  EXPECT_THROW(te::validate(c), std::invalid_argument);
  try {
    c = base();
    c.jitter_ns = 5'000'000;
    te::validate(c);
    FAIL() << "jitter larger than the period must be rejected";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("period"), std::string::npos) << e.what();
  }
}

TEST(TriggerSchedule, FaultScriptParses) {
  const auto j = nlohmann::json::parse(R"({"faults": [
      {"kind": "missing", "at": 3}, {"kind": "double", "at": 5, "gap_us": 700},
      {"kind": "burst", "at": 9, "count": 4, "gap_us": 1200.5}]})");
  const auto f = te::parse_fault_script(j);
  ASSERT_EQ(f.size(), 3u);
  EXPECT_EQ(f[0].kind, te::FaultKind::kMissing);
  EXPECT_EQ(f[1].kind, te::FaultKind::kDouble);
  EXPECT_EQ(f[1].gap_ns, 700'000);
  EXPECT_EQ(f[2].kind, te::FaultKind::kBurst);
  EXPECT_EQ(f[2].count, 4);
  EXPECT_EQ(f[2].gap_ns, 1'200'500);
  EXPECT_THROW(te::parse_fault_script(nlohmann::json::parse(R"({"faults":[{"kind":"x","at":1}]})")),
               std::invalid_argument);
  EXPECT_ANY_THROW(
      te::parse_fault_script(nlohmann::json::parse(R"({"faults":[{"kind":"missing"}]})")));
}

TEST(TriggerSchedule, CsvAndJsonLogsCarryEveryRow) {
  te::ScheduleConfig c = base(10);
  c.faults = {{te::FaultKind::kMissing, 2, 1, 0}, {te::FaultKind::kDouble, 6, 1, 0}};
  std::vector<te::SentPulse> log;
  for (const auto& p : te::make_schedule(c)) {
    const std::int64_t t = 1'000'000'000 + p.rise_offset_ns;
    log.push_back({p, t, p.sent() ? t + 10 : 0, p.sent() ? t + 10 + p.width_ns : 0});
  }
  std::stringstream csv;
  te::write_log_csv(csv, log);
  std::string line;
  std::getline(csv, line);
  EXPECT_EQ(line, "seq,nominal_index,kind,planned_rise_mono_ns,rise_mono_ns,fall_mono_ns,width_ns");
  int rows = 0, missing = 0, last_seq = -1;
  while (std::getline(csv, line)) {
    ++rows;
    const int seq = std::stoi(line.substr(0, line.find(',')));
    if (line.find(",missing,") != std::string::npos) {
      ++missing;
      EXPECT_EQ(seq, -1);
    } else {
      EXPECT_EQ(seq, last_seq + 1);
      last_seq = seq;
    }
  }
  EXPECT_EQ(rows, 11);
  EXPECT_EQ(missing, 1);
  EXPECT_EQ(last_seq, 9);  // 10 nominal - 1 missing + 1 double = 10 sent

  const nlohmann::json j = nlohmann::json::parse(te::log_to_json(c, log).dump());
  EXPECT_EQ(j.at("clock"), "CLOCK_MONOTONIC");
  ASSERT_EQ(j.at("pulses").size(), log.size());
  EXPECT_EQ(j.at("pulses")[7].at("kind"), "double");
  EXPECT_EQ(j.at("pulses")[7].at("rise_mono_ns").get<std::int64_t>(), log[7].rise_mono_ns);
  EXPECT_EQ(j.at("config").at("faults").size(), 2u);
}
