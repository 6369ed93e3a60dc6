// storetrack-host configuration: a JSON file (docs/fti-output.md, "storetrack-host") whose
// values the command line can override. Malformed files and values outside their range throw
// HostConfigError naming the file, the field and the allowed range.
#pragma once

#include <limits>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include "storetrack/geometry/transform.hpp"
#include "storetrack/ingest/exposure_aligner.hpp"
#include "storetrack/output/chapter10_writer.hpp"
#include "storetrack/pipeline/calibration_health.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"
#include "storetrack/pipeline/pose_tracker.hpp"

namespace storetrack::hostapp {

class HostConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A configured sender: datagrams of `unit_id` are accepted from `address` only.
struct UdpSource {
  int unit_id = 0;
  std::string address;
};

struct HostConfig {
  // input
  std::string udp_bind;  // required with UDP: the FTI interface's address (0.0.0.0 explicitly)
  int udp_port = 47100;  // 0: no UDP
  std::vector<UdpSource> udp_sources;  // empty: any sender (warned)
  // with udp_sources: other senders' datagrams are refused in the kernel (a socket filter), so a
  // flood cannot take the socket buffer from valid datagrams (docs/reliability.md)
  bool udp_kernel_filter = true;
  std::string udp_group;
  std::string udp_interface;
  std::vector<std::string> can_interfaces;
  // processing
  ingest::AlignerConfig aligner;  // camera_ids filled from the calibration
  pipeline::ProcessorConfig processor;
  // mark identification: processor.matcher (host/match MarkMatcher); its prior poses are fitted
  // to the initial mark positions, whose standard uncertainty per axis is this [m]
  double initial_marks_sigma_m = 0.005;
  std::map<int, geometry::Vec3> initial_marks_w;
  // where the store can be relative to the pylon (identifier.store_region; used by the
  // re-acquisition of a lost store, docs/matching.md): its nominal pose is the installation
  // priors' pylon-to-store pose; offsets in the pylon frame [m]
  struct StoreRegion {
    bool valid = false;
    double max_rotation_rad = 0;
    geometry::Vec3 min_offset_m = geometry::Vec3::Zero();
    geometry::Vec3 max_offset_m = geometry::Vec3::Zero();
  } store_region;
  // calibration_health (docs/calibration-health.md): the per-camera test of the extrinsics on
  // the pylon marks, and what a camera declared moved does (flag, correct, exclude)
  bool calibration_health_enabled = true;
  pipeline::CalibrationHealthConfig calibration_health;
  pipeline::CalibrationHealthMode calibration_health_mode = pipeline::CalibrationHealthMode::kFlag;
  // clearance (docs/clearance.md, "In the host"): the store-to-aircraft geometry file (the
  // clearance library's JSON; empty: no clearance, the sample's clearance fields are NaN) and
  // the alarm threshold on the k = 2 lower bound [m] (status bit clearance_alarm below it)
  std::string clearance_geometry;
  double clearance_alarm_threshold_m = std::numeric_limits<double>::quiet_NaN();
  // outputs
  std::string ch10_path, csv_path, marks_csv_path, rigid_csv_path, clearance_csv_path;
  std::string inetx_destination;
  std::uint32_t inetx_stream_id = 0x53540001;
  output::Chapter10Config ch10;
  // the recording thread's queue: at most this many exposures waiting for the files, 1..4096
  // (~10 s at 400 exposures/s); beyond it a sample is counted as dropped, never blocks the loop
  std::size_t recording_queue_items = 4096;
  // recording.raw_observations: every observation message received, as received, in the
  // Chapter 10 file's raw channel (docs/fti-output.md); on by default
  bool record_raw_observations = true;
  // live.store_envelope: the store's expected poses relative to the pylon (T_p_s), at most 256,
  // drawn by the live page as where the store's marks will fall in each image (the coverage
  // overlay, docs/live-view.md); each {"t_m": [x, y, z], "rotvec_rad": [rx, ry, rz]}
  std::vector<geometry::Transform> live_store_envelope_p;
};

/// Applies the JSON file's values onto `config` (fields not in the file keep their value).
void load_host_config(const std::string& path, HostConfig& config);
/// The same from JSON text; `origin` (the file name) starts every error message.
void parse_host_config(const std::string& json_text, const std::string& origin, HostConfig& config);
/// Sets the aligner's wait from milliseconds: finite, in (0, 60000]; `where` names the source.
void set_max_wait_ms(HostConfig& config, double max_wait_ms, const std::string& where);
/// Parses a --udp-source value "UNIT@a.b.c.d".
UdpSource parse_udp_source(const std::string& text);
/// Completes the configuration with the rig (camera and unit ids, in rig order) and checks what
/// depends on it or on several fields: min_cameras within the rig, a UDP bind address when UDP
/// is on, the source addresses, the calibration_health cameras in the rig.
void finish_host_config(HostConfig& config, const std::vector<int>& camera_ids,
                        const std::vector<int>& unit_ids);
/// Reads {"marks": [{"id": 0, "p_w_m": [x, y, z]}, ...]}.
std::map<int, geometry::Vec3> load_initial_marks(const std::string& path);
std::map<int, geometry::Vec3> parse_initial_marks(const std::string& json_text,
                                                  const std::string& origin);

}  // namespace storetrack::hostapp
