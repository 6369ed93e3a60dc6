// The live view (host/live, docs/live-view.md): the triple buffer never makes its writer wait and
// never hands out a torn snapshot; the publisher's snapshot holds exactly what it was given; the
// server serves its pages, refuses what it does not serve, and bounds its clients while the
// writer goes on publishing.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <gtest/gtest.h>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "storetrack/live/live_coverage.hpp"
#include "storetrack/live/live_server.hpp"
#include "storetrack/live/live_snapshot.hpp"

namespace st = storetrack;
using st::live::LivePublisher;
using st::live::LiveSnapshot;
using st::live::TripleBuffer;

namespace {

// --- the triple buffer --------------------------------------------------------------------

struct Payload {
  std::uint64_t seq = 0;
  std::array<std::uint64_t, 1024> words{};  // every word = seq: a torn copy shows
};

void fill(Payload& p, std::uint64_t seq) {
  p.seq = seq;
  p.words.fill(seq);
}

bool consistent(const Payload& p) {
  for (std::uint64_t w : p.words)
    if (w != p.seq) return false;
  return true;
}

TEST(TripleBuffer, WriterNeverWaitsForAReaderThatHoldsItsBuffer) {
  TripleBuffer<Payload> buffer;
  fill(buffer.back(), 1);
  buffer.publish();
  ASSERT_TRUE(buffer.take());
  // The reader now holds snapshot 1 and does not come back while the writer publishes 100000
  // more: were publish() to wait for the reader, this would never end.
  constexpr std::uint64_t kPublications = 100'000;
  for (std::uint64_t s = 2; s <= kPublications + 1; ++s) {
    fill(buffer.back(), s);
    buffer.publish();
  }
  EXPECT_EQ(buffer.front().seq, 1u);  // what the reader holds was never written over
  EXPECT_TRUE(consistent(buffer.front()));
  ASSERT_TRUE(buffer.take());
  EXPECT_EQ(buffer.front().seq, kPublications + 1);  // the newest, not an older one
  EXPECT_TRUE(consistent(buffer.front()));
  EXPECT_FALSE(buffer.take());  // nothing newer
}

TEST(TripleBuffer, ConcurrentReaderSeesWholeSnapshotsInOrder) {
  TripleBuffer<Payload> buffer;
  constexpr std::uint64_t kPublications = 20'000;
  std::atomic<bool> done{false};
  std::uint64_t torn = 0, backwards = 0, taken = 0, last = 0;
  std::thread reader([&] {
    while (true) {
      const bool finished = done.load();
      if (buffer.take()) {
        ++taken;
        if (!consistent(buffer.front())) ++torn;
        if (buffer.front().seq < last) ++backwards;
        last = buffer.front().seq;
      }
      if (finished) break;
    }
  });
  for (std::uint64_t s = 1; s <= kPublications; ++s) {
    fill(buffer.back(), s);
    buffer.publish();
  }
  done = true;
  reader.join();
  EXPECT_EQ(torn, 0u);
  EXPECT_EQ(backwards, 0u);
  EXPECT_GT(taken, 0u);
  EXPECT_EQ(last, kPublications);  // the last publication always reaches the reader
}

// --- the publisher ------------------------------------------------------------------------

st::msg::MarkObservations observation(int camera_id, int unit_id, std::uint32_t seq, int marks) {
  st::msg::MarkObservations o{};
  o.unit_id = static_cast<std::uint8_t>(unit_id);
  o.camera_id = static_cast<std::uint8_t>(camera_id);
  o.trigger_seq = seq;
  o.exposure_start_tai_ns = 1'000'000'000 + seq * 2'500'000LL;
  o.exposure_start_mono_ns = o.exposure_start_tai_ns;
  o.exposure_duration_ns = 500'000;
  o.clock_state = 2;
  o.flags = 0x4;
  o.mark_count = static_cast<std::uint8_t>(marks);
  for (int j = 0; j < marks; ++j) {
    o.marks[static_cast<std::size_t>(j)].x_px = 100.25f + 17.5f * static_cast<float>(j);
    o.marks[static_cast<std::size_t>(j)].y_px = 900.75f - 11.125f * static_cast<float>(j);
  }
  return o;
}

struct Rig {
  st::live::LiveRig ids{{3, 7, 9}, {0, 0, 1}};
  st::ingest::ExposureAligner aligner{st::ingest::AlignerConfig{{3, 7, 9}, {0, 0, 1}}};
};

TEST(LivePublisher, SnapshotHoldsWhatItWasGiven) {
  Rig rig;
  // Counters that are not all zero: one observation through the real aligner.
  std::vector<st::pipeline::AlignedExposure> released;
  rig.aligner.push(observation(3, 0, 41, 2), 1'000'000, released);

  st::pipeline::AlignedExposure e;
  e.trigger_seq = 42;
  e.cameras = {observation(3, 0, 42, 5), observation(7, 0, 42, 3)};
  e.missing_camera_mask = 0b100;  // camera 9
  e.exposure_mid_tai_ns = 1'105'250'000;
  e.closed_by_timeout = true;
  st::pipeline::ExposureResult r;
  r.cameras_used = 2;
  st::pipeline::MarkResult m;
  m.id = 12;
  m.body = 'p';
  m.excluded = true;
  m.observations.push_back({});
  m.observations.back().camera_id = 7;
  m.observations.back().mark_index = 1;
  m.observations.back().residual_px = {0.25, -0.5};
  r.marks.push_back(m);
  r.sample.trigger_seq = 42;
  r.sample.x_m = 0.125f;
  r.sample.u_z_m = 3e-4f;
  r.sample.status = 0x21;
  r.sample.coverage_factor = 2;
  r.T_w_p.valid = true;
  r.T_w_p.T.translation() = st::geometry::Vec3(1, 2, 3);

  LivePublisher publisher(rig.ids, 20'000'000);
  const st::live::LiveTotals totals{5, 4, 3, 1, 2};
  ASSERT_TRUE(publisher.on_exposure(e, r, true, rig.aligner, totals, 2'000'000'000));
  ASSERT_TRUE(publisher.take());
  const LiveSnapshot& s = publisher.front();
  EXPECT_EQ(s.publication, 1u);
  EXPECT_EQ(s.trigger_seq, 42u);
  EXPECT_EQ(s.missing_camera_mask, 0b100u);
  EXPECT_TRUE(s.closed_by_timeout);
  EXPECT_EQ(s.cameras_used, 2);
  EXPECT_TRUE(s.sample_written);
  ASSERT_EQ(s.camera_count, 3);
  for (int c = 0; c < 2; ++c) {
    const auto& cam = s.cameras[static_cast<std::size_t>(c)];
    const auto& obs = e.cameras[static_cast<std::size_t>(c)];
    EXPECT_EQ(cam.camera_id, obs.camera_id);
    EXPECT_TRUE(cam.delivered);
    EXPECT_EQ(cam.trigger_seq, obs.trigger_seq);
    EXPECT_EQ(cam.exposure_duration_ns, obs.exposure_duration_ns);
    EXPECT_EQ(cam.clock_state, obs.clock_state);
    EXPECT_EQ(cam.flags, obs.flags);
    ASSERT_EQ(cam.mark_count, obs.mark_count);
    for (int j = 0; j < cam.mark_count; ++j) {
      EXPECT_EQ(cam.marks[static_cast<std::size_t>(j)].x_px,
                obs.marks[static_cast<std::size_t>(j)].x_px);
      EXPECT_EQ(cam.marks[static_cast<std::size_t>(j)].y_px,
                obs.marks[static_cast<std::size_t>(j)].y_px);
      const bool identified = c == 1 && j == 1;
      EXPECT_EQ(cam.marks[static_cast<std::size_t>(j)].id, identified ? 12 : -1);
      EXPECT_EQ(cam.marks[static_cast<std::size_t>(j)].has_residual, identified);
    }
  }
  const auto& mark = s.cameras[1].marks[1];
  EXPECT_EQ(mark.body, 'p');
  EXPECT_TRUE(mark.excluded);
  EXPECT_EQ(mark.residual_x_px, 0.25f);
  EXPECT_EQ(mark.residual_y_px, -0.5f);
  EXPECT_EQ(s.cameras[0].last_clock_state, 2);
  EXPECT_EQ(s.cameras[0].last_seen_mono_ns, 2'000'000'000);
  EXPECT_EQ(s.cameras[2].last_seen_mono_ns, 0);  // camera 9: never seen
  EXPECT_FALSE(s.cameras[2].delivered);
  EXPECT_EQ(s.cameras[2].camera_id, 9);
  EXPECT_EQ(s.cameras[2].unit_id, 1);
  EXPECT_EQ(s.cameras[0].counters.received, rig.aligner.camera_counters()[0].received);
  EXPECT_EQ(s.cameras[0].counters.received, 1u);
  EXPECT_EQ(s.aligner.observations_in, rig.aligner.counters().observations_in);
  EXPECT_EQ(s.totals.samples_withheld, 1u);
  ASSERT_TRUE(s.has_sample);
  EXPECT_EQ(s.sample.x_m, 0.125f);
  EXPECT_EQ(s.sample.u_z_m, 3e-4f);
  EXPECT_EQ(s.sample.status, 0x21);
  EXPECT_TRUE(s.pylon.valid);
  EXPECT_EQ(s.pylon.T_w_b.translation(), st::geometry::Vec3(1, 2, 3));
  EXPECT_FALSE(s.store.valid);
  EXPECT_EQ(s.unit_count, 2);  // units 0 and 1

  // The JSON the page gets carries the same values (pixels to 1/1000 px).
  const auto j = nlohmann::json::parse(st::live::snapshot_json(s, {}, {}));
  EXPECT_EQ(j["exposure"]["trigger_seq"], 42);
  EXPECT_EQ(j["cameras"][0]["marks"].size(), 5u);
  EXPECT_NEAR(j["cameras"][0]["marks"][3]["x"].get<double>(), 100.25 + 17.5 * 3, 1e-3);
  EXPECT_EQ(j["cameras"][1]["marks"][1]["id"], 12);
  EXPECT_EQ(j["sample"]["x_m"].get<double>(), 0.125);
  EXPECT_TRUE(j["sample"]["y_m"].is_number());
}

TEST(LivePublisher, PublishesAtMostOncePerIntervalButKeepsTheNewestSample) {
  Rig rig;
  LivePublisher publisher(rig.ids, 20'000'000);
  st::pipeline::AlignedExposure e;
  e.cameras = {observation(3, 0, 1, 1)};
  st::pipeline::ExposureResult r;
  const st::live::LiveTotals totals{};
  r.sample.trigger_seq = 1;
  EXPECT_TRUE(publisher.on_exposure(e, r, true, rig.aligner, totals, 1'000'000'000));
  r.sample.trigger_seq = 2;  // 10 ms later: not published, but remembered
  EXPECT_FALSE(publisher.on_exposure(e, r, true, rig.aligner, totals, 1'010'000'000));
  r.sample.trigger_seq = 3;  // withheld: the page keeps showing the last WRITTEN sample
  EXPECT_TRUE(publisher.on_exposure(e, r, false, rig.aligner, totals, 1'020'000'000));
  ASSERT_TRUE(publisher.take());
  EXPECT_EQ(publisher.front().publication, 2u);
  EXPECT_FALSE(publisher.front().sample_written);
  EXPECT_EQ(publisher.front().sample.trigger_seq, 2u);
  EXPECT_EQ(publisher.publications(), 2u);
}

TEST(LivePublisher, HealthOfAUnitNotInTheRigIsCounted) {
  Rig rig;
  LivePublisher publisher(rig.ids);
  st::msg::UnitHealth h{};
  h.unit_id = 1;
  h.frames_dropped = 7;
  publisher.on_health(h, 5);
  h.unit_id = 200;
  publisher.on_health(h, 6);
  EXPECT_EQ(publisher.health_from_unknown_unit(), 1u);
  st::pipeline::AlignedExposure e;
  ASSERT_TRUE(publisher.on_exposure(e, {}, false, rig.aligner, {}, 10));
  ASSERT_TRUE(publisher.take());
  EXPECT_FALSE(publisher.front().units[0].heard);
  EXPECT_TRUE(publisher.front().units[1].heard);
  EXPECT_EQ(publisher.front().units[1].health.frames_dropped, 7u);
}

TEST(LivePublisher, RefusesMoreCamerasThanItHolds) {
  st::live::LiveRig big;
  for (int c = 0; c < 33; ++c) {
    big.camera_ids.push_back(c);
    big.unit_ids.push_back(0);
  }
  EXPECT_THROW(LivePublisher{big}, std::invalid_argument);
}

// --- the address ----------------------------------------------------------------------------

TEST(LiveAddress, BindAddressIsRequired) {
  for (const char* bad : {"", "8080", ":8080", "127.0.0.1:", "127.0.0.1:70000", "127.0.0.1:80a",
                          "example.org:80", "127.0.0.1"}) {
    try {
      st::live::parse_live_address(bad);
      ADD_FAILURE() << "accepted '" << bad << "'";
    } catch (const std::invalid_argument& e) {
      // The refusal says what is expected and that there is no default address.
      EXPECT_NE(std::string(e.what()).find("ADDR:PORT"), std::string::npos) << e.what();
    }
  }
  const auto a = st::live::parse_live_address("127.0.0.1:8080");
  EXPECT_EQ(a.host, "127.0.0.1");
  EXPECT_EQ(a.port, 8080);
  EXPECT_EQ(st::live::parse_live_address("0.0.0.0:0").port, 0);
}

// --- the server -----------------------------------------------------------------------------

int connect_to(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

// Reads what arrives within `timeout_ms` (or until `enough` bytes, or the peer closes).
std::string read_some(int fd, int timeout_ms, std::size_t enough = 1 << 20) {
  std::string out;
  const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
  char buf[4096];
  while (out.size() < enough) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                          end - std::chrono::steady_clock::now())
                          .count();
    if (left <= 0) break;
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(left)) <= 0) break;
    const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
    if (n <= 0) break;
    out.append(buf, static_cast<std::size_t>(n));
  }
  return out;
}

std::string request(int port, const std::string& text, int timeout_ms = 3000) {
  const int fd = connect_to(port);
  if (fd < 0) return "connect failed";
  (void)::send(fd, text.data(), text.size(), MSG_NOSIGNAL);
  std::string reply = read_some(fd, timeout_ms);
  ::close(fd);
  return reply;
}

std::string get(int port, const std::string& path) {
  return request(port, "GET " + path + " HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n");
}

int status_of(const std::string& reply) {
  if (reply.rfind("HTTP/1.1 ", 0) != 0) return 0;
  return std::stoi(reply.substr(9, 3));
}

st::live::LiveScene three_camera_scene() {
  st::live::LiveScene scene;
  for (int id : {3, 7, 9}) {
    scene.rig.cameras.push_back({});
    scene.rig.cameras.back().camera_id = id;
    scene.rig.cameras.back().unit_id = id == 9 ? 1 : 0;
  }
  return scene;
}

// A writer thread as the real-time loop: publishes an exposure of 3 cameras x 64 marks every
// call, records the longest call.
struct Writer {
  Rig rig;
  LivePublisher publisher{rig.ids, 0};
  std::atomic<bool> stop{false};
  std::atomic<std::uint64_t> calls{0};
  std::atomic<std::int64_t> longest_ns{0};
  std::thread thread;

  void start() {
    thread = std::thread([this] {
      st::pipeline::AlignedExposure e;
      e.cameras = {observation(3, 0, 1, 64), observation(7, 0, 1, 64), observation(9, 1, 1, 64)};
      st::pipeline::ExposureResult r;
      while (!stop) {
        const auto t0 = std::chrono::steady_clock::now();
        publisher.on_exposure(e, r, true, rig.aligner, {}, st::time::monotonic_now_ns());
        const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                            std::chrono::steady_clock::now() - t0)
                            .count();
        if (ns > longest_ns) longest_ns = ns;
        ++calls;
        std::this_thread::sleep_for(std::chrono::microseconds(500));
      }
    });
  }
  ~Writer() {
    stop = true;
    if (thread.joinable()) thread.join();
  }
};

// A server on a free loopback port fed by a running writer: what every server test starts from.
struct ServedRig {
  explicit ServedRig(int max_clients = st::live::LiveServerConfig{}.max_clients)
      : server(loopback_config(max_clients), three_camera_scene(), writer.publisher) {
    writer.start();
    server.start();
  }
  static st::live::LiveServerConfig loopback_config(int max_clients) {
    st::live::LiveServerConfig config;
    config.address = st::live::parse_live_address("127.0.0.1:0");
    config.max_clients = max_clients;
    return config;
  }
  Writer writer;
  st::live::LiveServer server;
};

TEST(LiveServer, ServesItsPagesAndRefusesTheRest) {
  ServedRig served;
  auto& [writer, server] = served;
  const int port = server.port();
  ASSERT_GT(port, 0);
  EXPECT_EQ(server.url(), "http://127.0.0.1:" + std::to_string(port) + "/");

  const std::string page = get(port, "/");
  EXPECT_EQ(status_of(page), 200);
  EXPECT_NE(page.find("<script src=\"/live.js\">"), std::string::npos);
  EXPECT_EQ(status_of(get(port, "/live.js")), 200);
  EXPECT_EQ(status_of(get(port, "/live.css")), 200);
  const std::string scene = get(port, "/api/scene");
  ASSERT_EQ(status_of(scene), 200);
  const auto scene_json = nlohmann::json::parse(scene.substr(scene.find("\r\n\r\n") + 4));
  EXPECT_EQ(scene_json["cameras"].size(), 3u);
  std::this_thread::sleep_for(std::chrono::milliseconds(200));  // a broadcast or two
  const std::string snapshot = get(port, "/api/snapshot");
  ASSERT_EQ(status_of(snapshot), 200);
  const auto snap = nlohmann::json::parse(snapshot.substr(snapshot.find("\r\n\r\n") + 4));
  EXPECT_GT(snap["publication"].get<int>(), 0);
  EXPECT_EQ(snap["cameras"][2]["marks"].size(), 64u);

  const std::string missing = get(port, "/etc/passwd");
  EXPECT_EQ(status_of(missing), 404);
  EXPECT_NE(missing.find("no page '/etc/passwd'"), std::string::npos);
  EXPECT_EQ(status_of(get(port, "/../live.js")), 404);
  // Read-only: no method but GET does anything.
  for (const char* method : {"POST", "PUT", "DELETE"}) {
    const int status = status_of(request(port, std::string(method) +
                                                   " / HTTP/1.1\r\nHost: x\r\nContent-Length: 2\r\n"
                                                   "Connection: close\r\n\r\n{}"));
    EXPECT_GE(status, 400) << method;
  }
  // Malformed requests: refused, and the server goes on serving.
  EXPECT_EQ(status_of(request(port, "GARBAGE\r\n\r\n")), 400);
  const std::string huge_header = "GET / HTTP/1.1\r\nX: " + std::string(100'000, 'a') + "\r\n\r\n";
  (void)request(port, huge_header, 1000);
  EXPECT_EQ(status_of(get(port, "/")), 200);
  EXPECT_GE(server.counters().not_found, 2u);
}

TEST(LiveServer, HundredConnectionsAtOnceAreBoundedAndTheWriterGoesOn) {
  ServedRig served(4);
  auto& [writer, server] = served;
  const int port = server.port();
  const std::uint64_t calls_before = writer.calls;

  constexpr int kConnections = 100;
  std::vector<int> fds;
  for (int i = 0; i < kConnections; ++i) {
    const int fd = connect_to(port);
    ASSERT_GE(fd, 0) << "connection " << i;
    fds.push_back(fd);
  }
  const std::string events = "GET /events HTTP/1.1\r\nHost: x\r\n\r\n";
  for (int fd : fds)
    ASSERT_EQ(::send(fd, events.data(), events.size(), MSG_NOSIGNAL),
              static_cast<ssize_t>(events.size()));
  int streaming = 0, refused = 0, other = 0;
  for (int fd : fds) {
    const int status = status_of(read_some(fd, 5000, 12));
    if (status == 200)
      ++streaming;
    else if (status == 503)
      ++refused;
    else
      ++other;
  }
  EXPECT_EQ(streaming, 4);
  EXPECT_EQ(refused, kConnections - 4);
  EXPECT_EQ(other, 0);
  EXPECT_EQ(server.counters().clients_peak, 4);
  EXPECT_EQ(server.counters().clients_refused, static_cast<std::uint64_t>(kConnections - 4));
  for (int fd : fds)
    ::close(fd);
  // The streams end when their next write fails (the next event, or the 1 s keep-alive).
  for (int i = 0; i < 50 && server.counters().clients_now > 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  EXPECT_EQ(server.counters().clients_now, 0);
  // A new client is served again.
  const int fd = connect_to(port);
  (void)::send(fd, events.data(), events.size(), MSG_NOSIGNAL);
  const std::string reply = read_some(fd, 3000, 4096);
  ::close(fd);
  EXPECT_EQ(status_of(reply), 200);
  EXPECT_NE(reply.find("event: snapshot"), std::string::npos);

  // The writer went on throughout; a call that waited on a client would take the write
  // timeout (1 s) or longer. The bound is far above scheduling noise on a loaded machine.
  EXPECT_GT(writer.calls - calls_before, 0u);
  EXPECT_LT(writer.longest_ns, 500'000'000) << "longest publish " << writer.longest_ns << " ns";
  std::printf("writer: %llu publications, longest call %.3f ms\n",
              static_cast<unsigned long long>(writer.calls.load()),
              static_cast<double>(writer.longest_ns.load()) * 1e-6);
}

TEST(LiveServer, StalledClientIsDroppedWhileAnotherKeepsReceiving) {
  ServedRig served;
  auto& [writer, server] = served;
  const int port = server.port();
  const std::string events = "GET /events HTTP/1.1\r\nHost: x\r\n\r\n";
  // The stalled client: a small receive buffer, and it never reads.
  const int stalled = ::socket(AF_INET, SOCK_STREAM, 0);
  const int small = 4096;
  ::setsockopt(stalled, SOL_SOCKET, SO_RCVBUF, &small, sizeof small);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ASSERT_EQ(::connect(stalled, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
  (void)::send(stalled, events.data(), events.size(), MSG_NOSIGNAL);
  const int reading = connect_to(port);
  (void)::send(reading, events.data(), events.size(), MSG_NOSIGNAL);
  std::size_t received = 0;
  const auto t0 = std::chrono::steady_clock::now();
  while (server.counters().clients_dropped == 0 &&
         std::chrono::steady_clock::now() - t0 < std::chrono::seconds(20))
    received += read_some(reading, 100).size();
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_EQ(server.counters().clients_dropped, 1u) << "after " << seconds << " s";
  EXPECT_EQ(server.counters().clients_now, 1);  // the reading client stays
  // The remaining client still gets events, at the page's rate: at least 10 per second (the
  // broadcaster's 20 Hz; the writer publishes at ~2 kHz, so every broadcast has a new snapshot).
  const auto t_rate = std::chrono::steady_clock::now();
  const std::string text = read_some(reading, 2000);
  const double rate_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_rate).count();
  std::size_t events_seen = 0;
  for (auto at = text.find("event: snapshot"); at != std::string::npos;
       at = text.find("event: snapshot", at + 1))
    ++events_seen;
  const double rate = static_cast<double>(events_seen) / rate_seconds;
  EXPECT_GE(rate, 10.0);
  std::printf(
      "stalled client dropped after %.2f s; the other received %zu bytes meanwhile, then "
      "%.1f events per second\n",
      seconds, received, rate);
  ::close(stalled);
  ::close(reading);
}

// --- the coverage overlay ------------------------------------------------------------------

// A camera 3 m in front of the pylon's origin looking back at it (camera z = world -x), with
// distortion, so a projection through the wrong frame or without the model would show.
st::camera::CalibratedCamera coverage_camera() {
  st::camera::Intrinsics in;
  in.fx = 1200;
  in.fy = 1190;
  in.cx = 950.3;
  in.cy = 520.7;
  in.dist = {-0.12, 0.03, 0.001, -0.0005, 0, 0, 0, 0};
  st::camera::CalibratedCamera cam;
  cam.camera_id = 3;
  cam.model = st::camera::CameraModel(in);
  st::geometry::Mat3 R_c_w;
  R_c_w << 0, 1, 0,  //
      0, 0, 1,       //
      -1, 0, 0;      // camera x = world y, camera y = world z, camera z = world -x
  cam.T_c_w.linear() = R_c_w;
  cam.T_c_w.translation() = -R_c_w * st::geometry::Vec3(3.0, 0.1, -0.2);
  return cam;
}

st::survey::RigidBodySurvey coverage_store() {
  st::survey::RigidBodySurvey store;
  store.name = "store";
  int id = 20;
  for (double x : {-0.4, 0.4})
    for (double y : {-0.1, 0.1})
      for (double z : {-0.15, 0.15})
        store.marks.push_back({id++, st::geometry::Vec3(x, y, z), 0.001});
  store.marks.push_back({id, st::geometry::Vec3(0.01, 0.02, 0.03), 0.001});  // an inside one
  return store;
}

st::geometry::Transform pose(const st::geometry::Vec3& rotvec, const st::geometry::Vec3& t) {
  st::geometry::Transform T = st::geometry::Transform::Identity();
  T.linear() = st::geometry::rotation_from_rotvec(rotvec);
  T.translation() = t;
  return T;
}

// The pixel of a store point, written out frame by frame (not through project_body_point):
// p_w = R_w_p (R_p_s p_s + t_p_s) + t_w_p, p_c = R_c_w p_w + t_c_w, then the camera model.
std::optional<st::geometry::Vec2> pixel_by_hand(const st::camera::CalibratedCamera& cam,
                                                const st::geometry::Transform& T_w_p,
                                                const st::geometry::Transform& T_p_s,
                                                const st::geometry::Vec3& p_s) {
  const st::geometry::Vec3 p_p = T_p_s.linear() * p_s + T_p_s.translation();
  const st::geometry::Vec3 p_w = T_w_p.linear() * p_p + T_w_p.translation();
  const st::geometry::Vec3 p_c = cam.T_c_w.linear() * p_w + cam.T_c_w.translation();
  return cam.model.project(p_c);
}

// Every point on or inside the counter-clockwise polygon (image axes, x right, y down: the
// hull's "counter-clockwise" is in x-y as written, so cross >= 0 for every edge).
bool inside_or_on(const std::vector<st::geometry::Vec2>& hull, const st::geometry::Vec2& p) {
  for (std::size_t i = 0; i < hull.size(); ++i) {
    const auto& a = hull[i];
    const auto& b = hull[(i + 1) % hull.size()];
    if ((b.x() - a.x()) * (p.y() - a.y()) - (b.y() - a.y()) * (p.x() - a.x()) < -1e-9) return false;
  }
  return true;
}

TEST(LiveCoverage, OutlinesAreTheStoreMarksProjectedThroughEachEnvelopePose) {
  const auto cam = coverage_camera();
  const auto store = coverage_store();
  const st::geometry::Transform T_w_p = pose({0.02, -0.03, 0.05}, {0.3, -0.1, 0.2});
  const std::vector<st::geometry::Transform> envelope = {
      pose({0, 0, 0}, {0, 0, -0.5}), pose({0.1, 0.2, -0.05}, {0.2, 0.1, -0.8}),
      pose({0, 0, 0.3}, {0.1, 0, -0.9}),
      pose({0, 0, 0}, {0, 3.0, -0.5}),   // far to the side: out of the image
      pose({0, 0, 0}, {3.5, 0, -0.5})};  // behind the camera (x > 3 m): out of the image
  const auto outlines = st::live::coverage_outlines(cam, T_w_p, envelope, store);
  ASSERT_EQ(outlines.size(), envelope.size());
  for (std::size_t k = 0; k < 3; ++k) {
    const auto& o = outlines[k];
    ASSERT_EQ(o.points.size(), store.marks.size()) << "pose " << k;
    EXPECT_FALSE(o.leaves_image) << "pose " << k;
    for (std::size_t i = 0; i < store.marks.size(); ++i) {
      const auto expected = pixel_by_hand(cam, T_w_p, envelope[k], store.marks[i].p_body);
      ASSERT_TRUE(expected);
      EXPECT_NEAR(o.points[i].x(), expected->x(), 1e-9) << "pose " << k << " mark " << i;
      EXPECT_NEAR(o.points[i].y(), expected->y(), 1e-9) << "pose " << k << " mark " << i;
      EXPECT_TRUE(inside_or_on(o.hull, o.points[i])) << "pose " << k << " mark " << i;
    }
    ASSERT_GE(o.hull.size(), 4u);  // a box seen in perspective: at least 4 corners
    for (const auto& v : o.hull)   // every corner is one of the marks
      EXPECT_TRUE(std::any_of(o.points.begin(), o.points.end(),
                              [&](const st::geometry::Vec2& p) { return p == v; }));
    // the inside mark (the last) is no corner
    EXPECT_TRUE(std::none_of(o.hull.begin(), o.hull.end(),
                             [&](const st::geometry::Vec2& v) { return v == o.points.back(); }));
  }
  EXPECT_TRUE(outlines[3].leaves_image);
  EXPECT_TRUE(outlines[4].leaves_image);
  EXPECT_LT(outlines[4].points.size(), store.marks.size());  // those behind are not drawn
}

TEST(LiveCoverage, HullOfASquareDropsInteriorAndCollinearPoints) {
  using V = st::geometry::Vec2;
  const auto hull = st::live::convex_hull(
      {V(0, 0), V(2, 0), V(1, 0), V(2, 2), V(0, 2), V(1, 1), V(0, 1), V(2, 2)});
  ASSERT_EQ(hull.size(), 4u);
  EXPECT_EQ(hull[0], V(0, 0));
  EXPECT_EQ(hull[1], V(2, 0));
  EXPECT_EQ(hull[2], V(2, 2));
  EXPECT_EQ(hull[3], V(0, 2));
  EXPECT_EQ(st::live::convex_hull({V(1, 1), V(1, 1)}).size(), 1u);
  EXPECT_EQ(st::live::convex_hull({V(0, 0), V(1, 1), V(2, 2)}).size(), 2u);
}

TEST(LiveCoverage, SnapshotCarriesTheOutlinesOnceThePylonIsSolved) {
  st::live::LiveScene scene;
  scene.rig.cameras.push_back(coverage_camera());
  scene.store = coverage_store();
  scene.store_envelope_p = {pose({0, 0, 0}, {0, 0, -0.5}), pose({0, 0, 0}, {0, 3.0, -0.5})};
  auto snapshot = std::make_unique<LiveSnapshot>();
  snapshot->camera_count = 1;
  snapshot->cameras[0].camera_id = 3;
  const st::live::LiveServerCounters counters;
  auto j = nlohmann::json::parse(st::live::snapshot_json(*snapshot, scene, counters));
  EXPECT_TRUE(j["cameras"][0]["coverage"].empty());  // no pylon pose yet: nothing to draw

  snapshot->pylon.valid = true;
  snapshot->pylon.T_w_b = pose({0.02, -0.03, 0.05}, {0.3, -0.1, 0.2});
  j = nlohmann::json::parse(st::live::snapshot_json(*snapshot, scene, counters));
  const auto& coverage = j["cameras"][0]["coverage"];
  ASSERT_EQ(coverage.size(), 2u);
  const auto outlines = st::live::coverage_outlines(scene.rig.cameras[0], snapshot->pylon.T_w_b,
                                                    scene.store_envelope_p, scene.store);
  for (std::size_t k = 0; k < 2; ++k) {
    EXPECT_EQ(coverage[k]["leaves_image"].get<bool>(), outlines[k].leaves_image);
    ASSERT_EQ(coverage[k]["hull"].size(), outlines[k].hull.size());
    for (std::size_t v = 0; v < outlines[k].hull.size(); ++v) {  // 1/10 px in the JSON
      EXPECT_NEAR(coverage[k]["hull"][v][0].get<double>(), outlines[k].hull[v].x(), 0.05);
      EXPECT_NEAR(coverage[k]["hull"][v][1].get<double>(), outlines[k].hull[v].y(), 0.05);
    }
  }
  EXPECT_FALSE(coverage[0]["leaves_image"].get<bool>());
  EXPECT_TRUE(coverage[1]["leaves_image"].get<bool>());
  EXPECT_EQ(nlohmann::json::parse(st::live::scene_json(scene))["store_envelope_poses"], 2);
}

}  // namespace
