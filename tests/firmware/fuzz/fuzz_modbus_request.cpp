// libFuzzer target: the unit's Modbus TCP request path as a network client reaches it: the
// real ModbusHealthServer (firmware/health, libmodbus) on 127.0.0.1, one connection per input
// carrying the input's bytes (after a first byte choosing maintenance mode or not), read to the
// server's close. The identity is locked and the search region must fit 640 x 480, as while
// the unit runs. Properties checked (abort when violated) against the model of a correct
// server (tests/firmware/health/modbus_model.hpp: the Modbus specification and docs/modbus.md),
// beyond "no crash, no UB":
//  - every whole request gets exactly the reply the model gives (never longer than the 260
//    bytes Modbus TCP allows; the transaction and unit id echoed; the exception the
//    documentation names); a header that is not Modbus TCP gets no reply and the close;
//  - the holding registers after the input are the model's: a refused write changes nothing,
//    unit_id and camera_id never change, an accepted write holds the ranges and
//    cross-register rules, the configuration generation counts accepted writes;
//  - the server's counters account for every request and every refusal, each in its own
//    counter.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <span>
#include <vector>

#include "modbus_model.hpp"
#include "storetrack/health/modbus_server.hpp"

namespace {

namespace health = storetrack::health;
namespace model = storetrack::health::model;

constexpr health::HoldingLimits kFrame{640, 480};

struct Unit {
  health::UnitCounters counters;
  health::ConfigStore store;
  std::unique_ptr<health::ModbusHealthServer> server;

  explicit Unit(bool maintenance) {
    store.lock_identity();
    store.set_limits(kFrame);
    health::ModbusServerConfig config;
    config.port = 0;
    config.maintenance = maintenance;
    server = std::make_unique<health::ModbusHealthServer>(config, counters, store);
    if (server->start() != 0) std::abort();
  }

  void reset_holding() {
    for (const health::RegisterDef& d : health::kRegisterMap)
      if (d.kind == health::RegisterKind::kHolding)
        store.set(static_cast<health::HoldingField>(d.field),
                  static_cast<std::uint16_t>(d.default_value));
  }

  model::Server::Holding holding() const {
    model::Server::Holding h{};
    store.read_all(h);
    return h;
  }
};

// Sends `bytes`, closes the sending side, returns everything the server sent until it closed.
std::vector<std::uint8_t> exchange(int port, std::span<const std::uint8_t> bytes) {
  const int s = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (s < 0 || connect(s, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) std::abort();
  timeval tv{5, 0};  // the server answers in microseconds; 5 s is a hung server
  setsockopt(s, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  if (!bytes.empty() &&
      send(s, bytes.data(), bytes.size(), MSG_NOSIGNAL) != static_cast<ssize_t>(bytes.size()))
    std::abort();
  shutdown(s, SHUT_WR);
  std::vector<std::uint8_t> got;
  std::uint8_t buf[4096];
  for (;;) {
    const ssize_t n = recv(s, buf, sizeof buf, 0);
    if (n == 0) break;
    if (n < 0) std::abort();  // timed out (the server never closed) or reset
    got.insert(got.end(), buf, buf + n);
  }
  close(s);
  return got;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static Unit locked(false), maintenance(true);
  if (size < 1) return 0;
  Unit& unit = (data[0] & 1) ? maintenance : locked;
  unit.reset_holding();
  const std::span<const std::uint8_t> stream(data + 1, size - 1);
  // Only what the server reads: after a bad header it closes, and bytes sent after that
  // would reset the connection before its replies are read.
  const model::Framing framing = model::frame_stream(stream);
  const std::span<const std::uint8_t> sent =
      framing.bad_header ? stream.first(framing.used) : stream;

  model::Server expected(unit.server->maintenance(), kFrame, unit.holding(),
                         unit.store.generation());
  const health::ModbusServerStats before = unit.server->stats();
  const std::vector<std::uint8_t> got = exchange(unit.server->bound_port(), sent);

  std::size_t at = 0;
  for (const auto request : framing.requests) {
    const model::Reply want = expected.answer(request);
    if (want.bytes.size() > model::kMaxAduBytes) std::abort();
    if (got.size() - at < want.bytes.size()) std::abort();  // a reply missing or short
    if (!model::same_reply(std::span(got).subspan(at, want.bytes.size()), want)) std::abort();
    at += want.bytes.size();
  }
  if (at != got.size()) std::abort();  // a reply nobody asked for

  if (unit.holding() != expected.holding()) std::abort();
  if (unit.store.generation() != expected.generation()) std::abort();
  const health::ModbusServerStats after = unit.server->stats();
  const model::Counts& n = expected.counts();
  if (after.requests - before.requests != n.requests ||
      after.refused_function - before.refused_function != n.refused_function ||
      after.refused_write_locked - before.refused_write_locked != n.refused_write_locked ||
      after.refused_value - before.refused_value != n.refused_value ||
      after.refused_identity - before.refused_identity != n.refused_identity ||
      after.writes_accepted - before.writes_accepted != n.writes_accepted ||
      after.malformed - before.malformed != n.malformed + (framing.bad_header ? 1 : 0))
    std::abort();
  return 0;
}
