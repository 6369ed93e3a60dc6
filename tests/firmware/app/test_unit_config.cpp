// storetrack-unit configuration: the shipped example parses and validates; typos and bad
// values are clear errors; the effective-config JSON reads back to the same configuration.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "unit_config.hpp"

namespace storetrack::unit {
namespace {

// Not std::string(DIR) + "/...": GCC 12 at -O2 for aarch64 reports a -Warray-bounds false
// positive on literal + string&& (the family of GCC bug 105329).
std::string example_config_path() {
  std::string path = STORETRACK_APP_CONFIG_DIR;
  path.append("/unit.example.json");
  return path;
}

TEST(UnitConfig, ShippedExampleIsValid) {
  UnitConfig c;
  ASSERT_NO_THROW(load_config_file(example_config_path(), c));
  EXPECT_NO_THROW(validate(c));
  EXPECT_EQ(c.source, SourceType::kV4l2);
  EXPECT_EQ(c.trigger.mode, TriggerMode::kGpioSlave);
  EXPECT_EQ(c.modbus_address, "127.0.0.1");
  EXPECT_FALSE(c.maintenance);
}

TEST(UnitConfig, UnknownKeysAndBadValuesAreErrors) {
  UnitConfig c;
  EXPECT_THROW(parse_config_json(R"({"unit_idd": 3})", "t", c), ConfigError);
  EXPECT_THROW(parse_config_json(R"({"trigger": {"mode": "gpio"}})", "t", c), ConfigError);
  EXPECT_THROW(parse_config_json(R"({"links": {"udp": [{"dest": "x"}]}})", "t", c), ConfigError);
  EXPECT_THROW(parse_config_json(R"({"unit_id": "three"})", "t", c), ConfigError);
  EXPECT_THROW(parse_config_json("{", "t", c), ConfigError);
  UnitConfig ok;
  ok.source = SourceType::kReplay;
  ok.replay.directory = "/tmp";
  EXPECT_NO_THROW(validate(ok));
  UnitConfig bad = ok;
  bad.trigger.rate_hz = 401;
  EXPECT_THROW(validate(bad), ConfigError);
  bad = ok;
  bad.unit_id = 255;
  EXPECT_THROW(validate(bad), ConfigError);
  bad = ok;
  bad.trigger.pulse_width_ns = 9'000'000;  // 90 % of 10 ms
  EXPECT_THROW(validate(bad), ConfigError);
  bad = ok;
  bad.source = SourceType::kSim;  // no scenario
  EXPECT_THROW(validate(bad), ConfigError);
}

TEST(UnitConfig, EffectiveConfigRoundTrips) {
  UnitConfig c;
  load_config_file(example_config_path(), c);
  UnitConfig back;
  parse_config_json(to_json(c), "round trip", back);
  EXPECT_EQ(to_json(back), to_json(c));
}

TEST(UnitConfig, Ptp4lClockSection) {
  UnitConfig c;
  parse_config_json(R"({"source": {"type": "none"}, "trigger": {"mode": "gpio-slave"},
      "clock_state": "ptp4l", "ptp4l": {"uds_path": "/run/ptp4l-eth1",
      "client_dir": "/tmp", "reply_timeout_ms": 20, "domain_number": 24,
      "lock_threshold_ns": 250, "lock_polls": 5, "holdover_s": 2.5, "offset_max_age_s": 2, "measure_only": true,
      "require_time_traceable": true}})",
                    "t", c);
  EXPECT_NO_THROW(validate(c));
  EXPECT_EQ(c.clock_state, "ptp4l");
  EXPECT_EQ(c.ptp4l.ptp4l.uds_path, "/run/ptp4l-eth1");
  EXPECT_EQ(c.ptp4l.ptp4l.client_dir, "/tmp");
  EXPECT_EQ(c.ptp4l.ptp4l.reply_timeout_ms, 20);
  EXPECT_EQ(c.ptp4l.ptp4l.domain_number, 24);
  EXPECT_EQ(c.ptp4l.lock.lock_threshold_ns, 250);
  EXPECT_EQ(c.ptp4l.lock.lock_polls, 5);
  EXPECT_EQ(c.ptp4l.lock.holdover_ns, 2'500'000'000);
  EXPECT_EQ(c.ptp4l.lock.offset_max_age_ns, 2'000'000'000);
  EXPECT_TRUE(c.ptp4l.lock.measure_only);
  EXPECT_TRUE(c.ptp4l.lock.require_time_traceable);
  UnitConfig back;
  parse_config_json(to_json(c), "round trip", back);
  EXPECT_EQ(to_json(back), to_json(c));
}

TEST(UnitConfig, Ptp4lValuesOutsideTheirRangesAreRefused) {
  UnitConfig c;
  EXPECT_THROW(parse_config_json(R"({"ptp4l": {"uds": "x"}})", "t", c), ConfigError);
  EXPECT_THROW(parse_config_json(R"({"ptp4l": {"domain_number": 128}})", "t", c), ConfigError);
  EXPECT_THROW(parse_config_json(R"({"ptp4l": {"holdover_s": -1}})", "t", c), ConfigError);
  EXPECT_THROW(parse_config_json(R"({"ptp4l": {"holdover_s": 3601}})", "t", c), ConfigError);
  EXPECT_THROW(parse_config_json(R"({"ptp4l": {"offset_max_age_s": 0}})", "t", c), ConfigError);
  auto refused = [](auto change) {
    UnitConfig u;
    u.source = SourceType::kNone;
    u.trigger.mode = TriggerMode::kGpioSlave;
    u.clock_state = "ptp4l";
    change(u);
    EXPECT_THROW(validate(u), ConfigError);
  };
  refused([](UnitConfig& u) { u.clock_state = "ptp"; });
  refused([](UnitConfig& u) { u.ptp4l.lock.lock_threshold_ns = 0; });
  refused([](UnitConfig& u) { u.ptp4l.lock.lock_threshold_ns = 2'000'000'000; });
  refused([](UnitConfig& u) { u.ptp4l.lock.lock_polls = 0; });
  refused([](UnitConfig& u) { u.ptp4l.lock.lock_polls = 101; });
  refused([](UnitConfig& u) { u.ptp4l.ptp4l.reply_timeout_ms = 0; });
  refused([](UnitConfig& u) { u.ptp4l.ptp4l.reply_timeout_ms = 334; });  // 3 x 334 > 1000 ms
  refused([](UnitConfig& u) { u.ptp4l.ptp4l.uds_path.clear(); });
  refused([](UnitConfig& u) { u.ptp4l.ptp4l.client_dir.clear(); });
  // The client's socket path must fit 107 bytes at start-up (ptp4l_client.hpp).
  refused([](UnitConfig& u) { u.ptp4l.ptp4l.client_dir = "/" + std::string(80, 'd'); });
  refused([](UnitConfig& u) { u.ptp4l.ptp4l.uds_path = "/" + std::string(120, 'u'); });
}

TEST(UnitConfig, NumbersAreReadExactlyOrRefused) {
  // Found by fuzz_unit_config. Before: camera_id 4294967296 ran as camera 0, 1.5 as 1, a
  // pulse width of 1e300 us and a float id beyond int were undefined behaviour, and 1e400 or
  // a number where a string belongs escaped as a JSON exception instead of a ConfigError.
  // A valid replay configuration around each bad value (so validate() is reached too).
  const auto replay_with = [](const char* member, const char* trigger_member) {
    std::string text = "{";
    text.append(member).append(
        R"("source": {"type": "replay", "replay": {"directory": "/tmp"}}, )");
    text.append(R"("trigger": {"mode": "sim", "rate_hz": 100)").append(trigger_member).append("}}");
    return text;
  };
  const std::vector<std::string> bad_configs = {
      replay_with(R"("camera_id": 4294967296, )", ""),
      replay_with(R"("unit_id": 1.5, )", ""),
      replay_with(R"("unit_id": 1e300, )", ""),
      replay_with(R"("exposure_us": -1, )", ""),
      replay_with("", R"(, "pulse_width_us": 1e300)"),
      replay_with("", R"(, "lines": [-1])"),
      replay_with(R"("run": {"duration_s": 1e400}, )", ""),
      R"({"source": {"type": 3}})",
      R"({"trigger": {"mode": true}})",
      R"({"links": {"udp": {"a": {"destination": "239.1.1.1:5"}}}})",
      R"({"modbus": {"maintenance": 1}})"};
  for (const std::string& bad : bad_configs) {
    UnitConfig c;
    EXPECT_THROW(
        {
          parse_config_json(bad, "t", c);
          validate(c);
        },
        ConfigError)
        << bad;
  }
  UnitConfig valid;
  EXPECT_NO_THROW(parse_config_json(replay_with("", ""), "t", valid));
  EXPECT_NO_THROW(validate(valid));
  UnitConfig c;
  parse_config_json(R"({"camera_id": 254, "trigger": {"lines": [0, 4294967295]}})", "t", c);
  EXPECT_EQ(c.camera_id, 254);
  EXPECT_EQ(c.trigger.lines, (std::vector<unsigned>{0, 4294967295u}));
}

// Issue 31: the refusal of unit_id stated the range of int, [-2147483648, 2147483647], where the
// unit accepts 0..254 (the Modbus holding register's range); typos name the nearest key.
TEST(UnitConfig, RefusalsStateTheTrueRangeAndTheNearestKey) {
  const auto message = [](const std::string& json) {
    UnitConfig c;
    try {
      parse_config_json(json, "unit.json", c);
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  EXPECT_EQ(message(R"({"unit_id": 255})"),
            "unit.json: unit_id: expected an integer in [0, 254], got 255");
  EXPECT_EQ(message(R"({"unit_id": 4294967296})"),
            "unit.json: unit_id: expected an integer in [0, 254], got 4294967296");
  EXPECT_EQ(message(R"({"camera_id": -1})"),
            "unit.json: camera_id: expected an integer in [0, 254], got -1");
  EXPECT_EQ(message(R"({"ptp4l": {"domain_number": 128}})"),
            "unit.json: ptp4l.domain_number: expected an integer in [0, 127], got 128");
  EXPECT_EQ(message(R"({"ptp4l": {"holdover_s": 3601}})"),
            "unit.json: ptp4l.holdover_s: expected a number in [0, 3600], got 3601");
  EXPECT_EQ(message(R"({"unit_idd": 3})"),
            "unit.json: unit_idd: unknown key (did you mean unit_id?)");
  EXPECT_EQ(message(R"({"trigger": {"rate": 100}})"),
            "unit.json: trigger.rate: unknown key (did you mean rate_hz?)");
  EXPECT_EQ(message(R"({"links": {"udp": [{"destinaton": "239.1.1.1:5"}]}})"),
            "unit.json: links.udp[0].destinaton: unknown key (did you mean destination?)");
  // The time uncertainty's keys (issue 30): typos named, ranges refused, "auto" or a number.
  EXPECT_EQ(message(R"({"time": {"latch_jiter_ns": 5}})"),
            "unit.json: time.latch_jiter_ns: unknown key (did you mean latch_jitter_ns?)");
  EXPECT_EQ(message(R"({"ptp4l": {"holdover_drift_pbb": 100}})"),
            "unit.json: ptp4l.holdover_drift_pbb: unknown key (did you mean holdover_drift_ppb?)");
  EXPECT_EQ(message(R"({"ptp4l": {"offset_window": 65}})"),
            "unit.json: ptp4l.offset_window: expected an integer in [1, 64], got 65");
  EXPECT_NE(message(R"({"time": {"sensor_start_jitter_ns": -1}})"), "accepted");
  EXPECT_NE(message(R"({"time": {"clock_sigma_ns": "automatic"}})"), "accepted");
  EXPECT_EQ(message(R"({"time": {"clock_sigma_ns": "auto", "latch_jitter_ns": 2000}})"),
            "accepted");
  EXPECT_EQ(message(R"({"unit_id": 254, "camera_id": 0})"), "accepted");
}

TEST(UnitConfig, PulseWidthAndDurationsSurvivePrintConfig) {
  // Found by fuzz_unit_config: 1.001 us was held as 1000 ns (1.001 * 1000 truncated), and
  // print-config wrote 1 us back; 0.3 s of holdover became 299999999 ns.
  UnitConfig c;
  parse_config_json(R"({"trigger": {"pulse_width_us": 1.001}, "ptp4l": {"holdover_s": 0.3}})", "t",
                    c);
  EXPECT_EQ(c.trigger.pulse_width_ns, 1001);
  EXPECT_EQ(c.ptp4l.lock.holdover_ns, 300'000'000);
  UnitConfig back;
  parse_config_json(to_json(c), "round trip", back);
  EXPECT_EQ(back.trigger.pulse_width_ns, 1001);
  EXPECT_EQ(to_json(back), to_json(c));
}

}  // namespace
}  // namespace storetrack::unit
