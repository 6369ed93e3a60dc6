// The live view's server (docs/live-view.md): serves the page and its assets (built into the
// program, nothing fetched from elsewhere) and streams the publisher's newest snapshot as
// Server-Sent Events. Read-only: it has no route that changes anything. It runs on threads of
// its own at a lower priority and reads the publisher's triple buffer only, so no client can
// make the real-time thread wait. cpp-httplib (Debian libcpp-httplib-dev) does the HTTP.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "storetrack/camera/calibration_file.hpp"
#include "storetrack/geometry/transform.hpp"
#include "storetrack/live/live_snapshot.hpp"
#include "storetrack/survey/survey.hpp"

namespace storetrack::live {

/// "ADDR:PORT" as given to --live. There is no default address: the operator names the
/// interface (0.0.0.0 serves every interface, only when written out).
struct LiveAddress {
  std::string host;
  int port = 0;  ///< 0: any free port (tests; the URL printed names the one bound)
};
/// Parses ADDR:PORT (IPv4 dotted quad or "localhost"); throws std::invalid_argument whose
/// what() says what is wrong and what is expected.
LiveAddress parse_live_address(const std::string& text);

struct LiveServerConfig {
  LiveAddress address;
  int max_clients = 24;        ///< event streams at once; more are refused (503)
  double update_hz = 20;       ///< event rate, 10..50
  double write_timeout_s = 1;  ///< a client that takes no data this long is dropped
  int socket_send_buffer = 0;  ///< SO_SNDBUF of client sockets [bytes]; 0: 64 KiB
  int worker_nice = 10;        ///< nice of the server's threads (the real-time loop: 0)
};

/// What the page draws that does not change during a run: the rig and the surveys.
struct LiveScene {
  camera::RigCalibration rig;
  survey::RigidBodySurvey pylon, store;
  /// The store's expected poses relative to the pylon, T_p_s (host.json "live"
  /// "store_envelope"); empty: no coverage overlay (live_coverage.hpp).
  std::vector<geometry::Transform> store_envelope_p;
};

struct LiveServerCounters {
  std::uint64_t requests = 0, not_found = 0, clients_refused = 0, clients_dropped = 0,
                events_sent = 0, snapshots_read = 0;
  int clients_now = 0, clients_peak = 0;
};

class LiveServer {
 public:
  LiveServer(const LiveServerConfig& config, LiveScene scene, LivePublisher& publisher);
  ~LiveServer();
  LiveServer(const LiveServer&) = delete;
  LiveServer& operator=(const LiveServer&) = delete;

  /// Binds and starts the threads; throws std::runtime_error naming the address and the cause.
  void start();
  /// Ends every stream and joins the threads (also done by the destructor).
  void stop();
  /// http://HOST:PORT/ with the port bound.
  std::string url() const;
  int port() const;
  LiveServerCounters counters() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// The snapshot as the page's JSON (also GET /api/snapshot); the scene's surveys are projected
/// through the snapshot's body poses into every camera. Tests read it too.
std::string snapshot_json(const LiveSnapshot& snapshot, const LiveScene& scene,
                          const LiveServerCounters& server);
/// The scene as the page's JSON (GET /api/scene).
std::string scene_json(const LiveScene& scene);

}  // namespace storetrack::live
