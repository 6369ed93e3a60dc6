// storetrack-host configuration: every value outside its range is refused with a message naming
// the field and the range, never cast (a NaN wait, a port wrapping to 16 bits, a negative
// max_pending turned into 2^64 - 1). The accepted values are checked against what was written.
#include "host_config.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>

namespace storetrack::hostapp {
namespace {

class ConfigFile {
 public:
  explicit ConfigFile(const std::string& text) {
    path_ = ::testing::TempDir() + "host_config_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name() + ".json";
    std::ofstream(path_) << text;
  }
  ~ConfigFile() { std::remove(path_.c_str()); }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

// Loads `json` and completes it with a 4-camera rig; returns the error message ("" if none).
std::string load(const std::string& json, HostConfig* out = nullptr) {
  ConfigFile f(json);
  HostConfig c;
  c.udp_bind = "127.0.0.1";
  try {
    load_host_config(f.path(), c);
    finish_host_config(c, {0, 1, 2, 3}, {0, 0, 1, 1});
  } catch (const HostConfigError& e) {
    return e.what();
  }
  if (out) *out = c;
  return "";
}

void expect_refused(const std::string& json, const std::string& field, const std::string& range) {
  const std::string msg = load(json);
  EXPECT_NE(msg.find(field), std::string::npos) << json << " -> '" << msg << "'";
  EXPECT_NE(msg.find(range), std::string::npos) << json << " -> '" << msg << "'";
}

TEST(HostConfig, AlignerWaitAndSpreadOutsideTheirRangeAreRefused) {
  for (const char* v : {"0", "-1", "60001", "1e300", "\"10\""})
    expect_refused(std::string(R"({"aligner": {"max_wait_ms": )") + v + "}}", "max_wait_ms",
                   "(0, 60000]");
  // JSON has no NaN literal; a NaN reaches the aligner through the command line.
  HostConfig c;
  for (const double v : {std::nan(""), -1.0, 0.0, 1e300}) {
    try {
      set_max_wait_ms(c, v, "--max-wait-ms");
      ADD_FAILURE() << v << " accepted";
    } catch (const HostConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("--max-wait-ms"), std::string::npos);
    }
  }
  for (const char* v : {"-0.5", "1001", "1e300", "null"})
    expect_refused(std::string(R"({"aligner": {"max_mid_time_spread_ms": )") + v + "}}",
                   "max_mid_time_spread_ms", "[0, 1000]");
}

TEST(HostConfig, AlignerIntegersOutsideTheirRangeAreRefused) {
  for (const char* v : {"0", "-1", "4097", "18446744073709551615", "2.5", "true"})
    expect_refused(std::string(R"({"aligner": {"max_pending": )") + v + "}}", "max_pending",
                   "[1, 4096]");
  for (const char* v : {"0", "-3", "33", "4294967297"})
    expect_refused(std::string(R"({"aligner": {"min_cameras": )") + v + "}}", "min_cameras",
                   "[1, 32]");
  // Within 1..32 but more than the rig has.
  expect_refused(R"({"aligner": {"min_cameras": 5}})", "min_cameras", "[1, 4]");
  for (const char* v : {"0", "100001"})
    expect_refused(std::string(R"({"aligner": {"max_sequence_lead": )") + v + "}}",
                   "max_sequence_lead", "[1, 100000]");
}

// clearance (docs/clearance.md, "In the host"): a threshold that is not a number, and the
// geometry without a threshold or the reverse, refused by name.
TEST(HostConfig, ClearanceKeysAreCheckedByName) {
  expect_refused(R"({"clearance": {"geometry": "g.json", "alarm_threshold_m": "0.5"}})",
                 "clearance.alarm_threshold_m", "number");
  expect_refused(R"({"clearance": {"geometry": "g.json"}})", "clearance", "needs both geometry");
  expect_refused(R"({"clearance": {"alarm_threshold_m": 0.5}})", "clearance",
                 "needs both geometry");
  expect_refused(R"({"clearance": {"geometry": "g.json", "threshold_m": 0.5}})",
                 "clearance.threshold_m", "unknown key");
  HostConfig c;
  ASSERT_EQ(load(R"({"clearance": {"geometry": "g.json", "alarm_threshold_m": 0.3}})", &c), "");
  EXPECT_EQ(c.clearance_geometry, "g.json");
  EXPECT_EQ(c.clearance_alarm_threshold_m, 0.3);
}

// calibration_health (docs/calibration-health.md): the mode by name, the ranges, and a camera the
// rig does not have refused by name.
TEST(HostConfig, CalibrationHealthKeysAreCheckedByName) {
  expect_refused(R"({"calibration_health": {"mode": "fix"}})", "calibration_health.mode",
                 "flag, correct, exclude");
  expect_refused(R"({"calibration_health": {"cameras": [0, 9]}})", "calibration_health.cameras",
                 "camera 9 is not in the rig (its cameras: 0, 1, 2, 3)");
  expect_refused(R"({"calibration_health": {"window_exposures": 1}})", "window_exposures",
                 "[2, 100000]");
  expect_refused(R"({"calibration_health": {"false_alarm_probability": 0.5}})",
                 "false_alarm_probability", "(0, 0.5)");
  expect_refused(R"({"calibration_health": {"min_pylon_marks": 2}})", "min_pylon_marks",
                 "[3, 1024]");
  expect_refused(R"({"calibration_health": {"windows": 3}})", "calibration_health.windows",
                 "unknown key");
  HostConfig c;
  ASSERT_EQ(load(R"({"calibration_health": {"mode": "correct", "window_exposures": 20,
      "baseline_windows": 10, "false_alarm_probability": 1e-7, "cameras": [1, 3]}})",
                 &c),
            "");
  EXPECT_EQ(c.calibration_health_mode, pipeline::CalibrationHealthMode::kCorrect);
  EXPECT_EQ(c.calibration_health.window_exposures, 20);
  EXPECT_EQ(c.calibration_health.baseline_windows, 10);
  EXPECT_EQ(c.calibration_health.false_alarm_probability, 1e-7);
  EXPECT_EQ(c.calibration_health.camera_ids, (std::vector<int>{1, 3}));
  EXPECT_TRUE(c.calibration_health_enabled);
}

TEST(HostConfig, UdpPortBindAndSourcesAreChecked) {
  // 65536 + 47100 used to wrap to port 47100; -1 to 65535.
  for (const char* v : {"112636", "65536", "-1", "4294967297", "47100.5"})
    expect_refused(std::string(R"({"udp": {"port": )") + v + "}}", "port", "[0, 65535]");
  expect_refused(R"({"udp": {"bind": "eth0"}})", "bind", "IPv4");
  expect_refused(R"({"udp": {"sources": [{"unit_id": 255, "address": "10.0.0.1"}]}})", "unit_id",
                 "[0, 254]");
  expect_refused(R"({"udp": {"sources": [{"unit_id": 1, "address": "10.0.0"}]}})", "address",
                 "IPv4");
  // No default bind to every interface: UDP without a bind address is refused.
  ConfigFile f(R"({"udp": {"port": 47100}})");
  HostConfig c;
  load_host_config(f.path(), c);
  EXPECT_THROW(finish_host_config(c, {0}, {0}), HostConfigError);
  c.udp_port = 0;  // CAN only: no bind needed
  EXPECT_NO_THROW(finish_host_config(c, {0}, {0}));
}

TEST(HostConfig, ValuesInRangeAreAppliedExactly) {
  HostConfig c;
  ASSERT_EQ(load(R"({"udp": {"port": 65535, "sources": [{"unit_id": 3, "address": "10.1.2.3"}]},
                     "aligner": {"max_wait_ms": 2.5, "max_mid_time_spread_ms": 0.75,
                                 "max_pending": 4096, "min_cameras": 4,
                                 "max_sequence_lead": 8}})",
                 &c),
            "");
  EXPECT_EQ(c.udp_port, 65535);
  ASSERT_EQ(c.udp_sources.size(), 1u);
  EXPECT_EQ(c.udp_sources[0].unit_id, 3);
  EXPECT_EQ(c.udp_sources[0].address, "10.1.2.3");
  EXPECT_EQ(c.aligner.max_wait_ns, 2'500'000);
  EXPECT_EQ(c.aligner.max_mid_time_spread_ns, 750'000);
  EXPECT_EQ(c.aligner.max_pending, 4096u);
  EXPECT_EQ(c.aligner.min_cameras, 4);
  EXPECT_EQ(c.aligner.max_sequence_lead, 8u);
  EXPECT_EQ(c.aligner.camera_ids, (std::vector<int>{0, 1, 2, 3}));
  EXPECT_EQ(c.aligner.unit_ids, (std::vector<int>{0, 0, 1, 1}));
}

TEST(HostConfig, UdpSourceOption) {
  const UdpSource s = parse_udp_source("7@192.168.1.20");
  EXPECT_EQ(s.unit_id, 7);
  EXPECT_EQ(s.address, "192.168.1.20");
  for (const char* bad : {"7", "@1.2.3.4", "x@1.2.3.4", "7x@1.2.3.4"})
    EXPECT_THROW(parse_udp_source(bad), HostConfigError) << bad;
}

// Found by fuzz_host_config / fuzz_initial_marks (tests/host/fuzz): these integers were read with
// nlohmann's get<int>, so 1e300 was an out-of-range cast (UBSan: "1e+300 is outside the range of
// representable values of type 'int'") and 2.5 became 2 silently.
TEST(HostConfig, FuzzFindingsIntegerFieldsRefuseFloats) {
  struct Field {
    const char* json_prefix;
    const char* name;
    const char* range;
  };
  const Field fields[] = {
      {R"({"processor": {"min_cameras_per_mark": )", "min_cameras_per_mark", "[1, 32]"},
      {R"({"processor": {"min_pose_marks": )", "min_pose_marks", "[3, 1024]"},
      {R"({"processor": {"reference_camera_id": )", "reference_camera_id", "[-1, 254]"},
      {R"({"chapter10": {"max_messages_per_packet": )", "max_messages_per_packet", "[1, 65535]"}};
  for (const auto& f : fields)
    for (const char* value : {"1e300", "2.5", "-1e300", "4294967297"})
      expect_refused(std::string(f.json_prefix) + value + "}}", f.name, f.range);
}

std::string initial_marks_error(const std::string& json) {
  ConfigFile f(json);
  try {
    load_initial_marks(f.path());
  } catch (const HostConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(HostConfig, FuzzFindingsInitialMarkIdsAreIntegersAndUnique) {
  const std::string xyz = R"(, "p_w_m": [1, 2, 3]})";
  for (const char* id : {"1e300", "2.5", "-1", "4294967296"})
    EXPECT_NE(initial_marks_error(std::string(R"({"marks": [{"id": )") + id + xyz + "]}")
                  .find("marks[0].id: expected an integer in [0, 1000000]"),
              std::string::npos)
        << id;
  // A second entry with the same id silently replaced the first.
  EXPECT_NE(initial_marks_error(R"({"marks": [{"id": 4)" + xyz + R"(, {"id": 4)" + xyz + "]}")
                .find("marks[1]: duplicate mark id 4"),
            std::string::npos);
  EXPECT_EQ(initial_marks_error(R"({"marks": [{"id": 4)" + xyz + R"(, {"id": 5)" + xyz + "]}"), "");
}

// Issue 31: these typos ran with exit 0 and the defaults. Each is refused naming the file, the
// key's path and the nearest known key (the program's own refusal: test_host_config_typos).
TEST(HostConfig, TyposAreRefusedWithTheNearestKnownKey) {
  struct Case {
    const char* json;
    const char* message;
  };
  const Case cases[] = {
      {R"({"aligner": {"max_wait": 10}})",
       ": aligner.max_wait: unknown key (did you mean max_wait_ms?)"},
      {R"({"algner": {"max_wait_ms": 10}})", ": algner: unknown key (did you mean aligner?)"},
      {R"({"udp": {"prot": 5}})", ": udp.prot: unknown key (did you mean port?)"},
      {R"({"aligner": [1, 2]})", ": aligner: expected an object, got an array"},
      {R"({"processor": {"store_id": 1, "coverage_facter": 2}})",
       ": processor.coverage_facter: unknown key (did you mean coverage_factor?)"},
      {R"({"identifier": {"store_region": {"min_offset_m": [0, 0, 0], "max_offset_m": [1, 1, 1],
           "max_rotation": 10}}})",
       ": identifier.store_region.max_rotation: unknown key (did you mean max_rotation_deg?)"},
      {R"({"recording": {"queue": 16}})",
       ": recording.queue: unknown key (did you mean queue_items?)"},
  };
  for (const Case& k : cases) {
    const std::string msg = load(k.json);
    EXPECT_NE(msg.find(".json"), std::string::npos) << msg;  // the file
    EXPECT_NE(msg.find(k.message), std::string::npos) << k.json << " -> '" << msg << "'";
  }
  EXPECT_NE(initial_marks_error(R"({"marks": [{"id": 4, "p_w": [1, 2, 3]}]})")
                .find("marks[0].p_w_m: missing (is p_w a typo of it?)"),
            std::string::npos);
}

TEST(HostConfig, RecordingQueueBoundIsChecked) {
  for (const char* v : {"0", "-1", "4097", "2.5", "\"16\""})
    expect_refused(std::string(R"({"recording": {"queue_items": )") + v + "}}", "queue_items",
                   "[1, 4096]");
  HostConfig c;
  ASSERT_EQ(load(R"({"recording": {"queue_items": 16}})", &c), "");
  EXPECT_EQ(c.recording_queue_items, 16u);
  HostConfig defaults;
  EXPECT_EQ(defaults.recording_queue_items, 4096u);  // RecordingWriter::kQueueItems
}

TEST(HostConfig, RawObservationRecordingSwitch) {
  HostConfig defaults;
  EXPECT_TRUE(defaults.record_raw_observations);  // on unless the configuration says otherwise
  HostConfig c;
  ASSERT_EQ(load(R"({"recording": {"raw_observations": false}})", &c), "");
  EXPECT_FALSE(c.record_raw_observations);
  for (const char* v : {"0", "1", "\"false\"", "null", "[true]"})
    EXPECT_NE(load(std::string(R"({"recording": {"raw_observations": )") + v + "}}")
                  .find("recording.raw_observations"),
              std::string::npos)
        << v;
  EXPECT_NE(load(R"({"recording": {"raw_observation": false}})")
                .find("recording.raw_observation: unknown key (did you mean raw_observations?)"),
            std::string::npos);
}

TEST(HostConfig, LiveStoreEnvelopeIsReadAsPylonToStorePoses) {
  HostConfig c;
  ASSERT_EQ(load(R"({"live": {"store_envelope": [
                  {"t_m": [0.1, -0.2, 0.3], "rotvec_rad": [0, 0, 0]},
                  {"t_m": [0, 0, 0.5], "rotvec_rad": [0, 0.2, 0]}]}})",
                 &c),
            "");
  ASSERT_EQ(c.live_store_envelope_p.size(), 2u);
  EXPECT_TRUE(c.live_store_envelope_p[0].translation().isApprox(geometry::Vec3(0.1, -0.2, 0.3)));
  EXPECT_TRUE(c.live_store_envelope_p[0].linear().isIdentity(0));
  // rotvec (0, 0.2, 0): 0.2 rad about y
  EXPECT_NEAR(c.live_store_envelope_p[1].linear()(0, 2), std::sin(0.2), 1e-15);
  EXPECT_NEAR(c.live_store_envelope_p[1].linear()(0, 0), std::cos(0.2), 1e-15);
  EXPECT_DOUBLE_EQ(c.live_store_envelope_p[1].translation().z(), 0.5);
  HostConfig defaults;
  EXPECT_TRUE(defaults.live_store_envelope_p.empty());  // no overlay unless configured

  EXPECT_NE(load(R"({"live": {"store_envelope": []}})").find("live.store_envelope"),
            std::string::npos);
  EXPECT_NE(load(R"({"live": {"store_envelope": [{"t_m": [0, 0, 0]}]}})")
                .find("live.store_envelope[0].rotvec_rad: missing"),
            std::string::npos);
  EXPECT_NE(load(R"({"live": {"store_envelope": [{"t_m": [0, 0], "rotvec_rad": [0, 0, 0]}]}})")
                .find("live.store_envelope[0].t_m"),
            std::string::npos);
  EXPECT_NE(load(R"({"live": {"store_envelop": []}})").find("live.store_envelop: unknown key"),
            std::string::npos);
}

TEST(HostConfig, EverySectionNamesTheKeyOfABadValue) {
  // Paths through each section's reader that the range tests above do not reach: a wrong JSON
  // type, a value outside a (0, x) bound, a removed key, a malformed list. The message names the
  // section and the key, so the user can find the line.
  struct Case {
    const char* json;
    const char* key;
  };
  const Case cases[] = {
      {R"([1, 2])", "(top level): expected an object, got an array"},
      {R"({"udp": {"group": 5}})", "udp.group: expected a string"},
      {R"({"udp": {"sources": {"unit_id": 1}}})", "udp.sources: expected an array"},
      {R"({"udp": {"sources": [7]}})", "udp.sources[0]: expected an object"},
      {R"({"udp": {"sources": [{"unit_id": 1}]}})", "udp.sources[0].address: missing"},
      {R"({"can_interfaces": "can0"})", "can_interfaces: expected an array"},
      {R"({"processor": {"coverage_factor": "two"}})",
       "processor.coverage_factor: expected a number in > 0"},
      {R"({"processor": {"store_id": 255}})",
       "processor.store_id: expected an integer in [0, 254]"},
      {R"({"processor": {"max_pose_rotation_sigma_rad": 0}})",
       "processor.max_pose_rotation_sigma_rad: expected a number in > 0"},
      {R"({"pose_tracker": {"max_gap_s": -1}})",
       "pose_tracker.max_gap_s: expected a number in >= 0"},
      {R"({"pose_tracker": {"accel_sigma_m_s2": "x"}})",
       "pose_tracker.accel_sigma_m_s2: expected a number in > 0"},
      {R"({"pose_tracker": {"mean_accel_p_m_s2": [0, 9.8]}})",
       "pose_tracker.mean_accel_p_m_s2: expected an array of 3"},
      {R"({"pose_tracker": {"ejector_accel_max_m_s2": -1}})",
       "pose_tracker.ejector_accel_max_m_s2: expected a number in >= 0"},
      {R"({"pose_tracker": {"ejector_duration_max_s": "80 ms"}})",
       "pose_tracker.ejector_duration_max_s: expected a number in >= 0"},
      {R"({"identifier": {"gate_px": 3}})", "identifier.gate_px: no longer exists"},
      {R"({"identifier": {"gate_probability": 1}})",
       "identifier.gate_probability: expected a number in (0, 1)"},
      {R"({"identifier": {"keep_single_view": 3}})",
       "identifier.keep_single_view: expected true or false"},
      {R"({"identifier": {"initial_marks_sigma_m": 0}})",
       "identifier.initial_marks_sigma_m: expected a number in > 0"},
      {R"({"identifier": {"min_reacquisition_marks": 2}})",
       "identifier.min_reacquisition_marks: expected an integer in [3, 64]"},
      {R"({"identifier": {"reacquisition_retry_s": -1}})",
       "identifier.reacquisition_retry_s: expected a number in [0, 10]"},
      {R"({"identifier": {"store_region": {"max_offset_m": [1, 1, 1]}}})",
       "identifier.store_region.min_offset_m: missing"},
      {R"({"identifier": {"store_region": {"min_offset_m": [0, 0, 2], "max_offset_m": [1, 1, 1]}}})",
       "identifier.store_region: min_offset_m must be <= max_offset_m"},
      {R"({"identifier": {"store_region": {"max_rotation_deg": 0, "min_offset_m": [0, 0, 0],
           "max_offset_m": [1, 1, 1]}}})",
       "identifier.store_region.max_rotation_deg: expected a number in (0, 180]"},
      {R"({"chapter10": {"data_checksum": "yes"}})",
       "chapter10.data_checksum: expected true or false"},
      {R"({"chapter10": {"test_point": 12}})", "chapter10.test_point: expected a string"},
  };
  for (const Case& k : cases) {
    const std::string msg = load(k.json);
    EXPECT_NE(msg.find(k.key), std::string::npos) << k.json << " -> '" << msg << "'";
  }
  // Each section's good values still load (the split readers apply them).
  HostConfig c;
  ASSERT_EQ(load(R"({"processor": {"coverage_factor": 3, "store_id": 9},
                     "pose_tracker": {"max_gap_s": 0.05, "mean_accel_p_m_s2": [0, 0, 4.9]},
                     "identifier": {"gate_probability": 0.999, "initial_marks_sigma_m": 0.01,
                                    "store_region": {"max_rotation_deg": 30,
                                                     "min_offset_m": [-1.5, -0.5, -0.1],
                                                     "max_offset_m": [0.1, 0.5, 5]}},
                     "chapter10": {"test_point": "TP-7", "data_checksum": true}})",
                 &c),
            "");
  EXPECT_EQ(c.processor.coverage_factor, 3);
  EXPECT_EQ(c.processor.store_id, 9);
  EXPECT_EQ(c.processor.pose_tracker.max_gap_s, 0.05);
  EXPECT_EQ(c.processor.pose_tracker.mean_accel_p_m_s2,
            geometry::Vec3(0, 0, 4.9));  // a 0.5 g test point
  EXPECT_EQ(c.processor.matcher.gate_probability, 0.999);
  EXPECT_EQ(c.initial_marks_sigma_m, 0.01);
  EXPECT_TRUE(c.store_region.valid);
  EXPECT_NEAR(c.store_region.max_rotation_rad, 30 * M_PI / 180, 1e-12);
  EXPECT_EQ(c.store_region.min_offset_m, geometry::Vec3(-1.5, -0.5, -0.1));
  EXPECT_EQ(c.store_region.max_offset_m, geometry::Vec3(0.1, 0.5, 5));
  EXPECT_EQ(c.ch10.test_point, "TP-7");
  EXPECT_TRUE(c.ch10.data_checksum);
}

}  // namespace
}  // namespace storetrack::hostapp
