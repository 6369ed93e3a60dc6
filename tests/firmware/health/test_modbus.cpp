// The Modbus map through a REAL libmodbus client on 127.0.0.1: reads, refusals (write outside
// maintenance, fc 0x17, other function codes), range checks, malformed raw requests; and the
// documentation generated from the one register table; thousands of random requests checked
// against the model of a correct server (modbus_model.hpp).
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <random>
#include <span>
#include <sstream>
#include <thread>
#include <vector>

#include "modbus_model.hpp"
#include "storetrack/health/board_temperature.hpp"
#include "storetrack/health/modbus_server.hpp"
#include "storetrack/health/register_map.hpp"
#include "storetrack/health/unit_state.hpp"

namespace storetrack::health {
namespace {

struct Client {
  modbus_t* ctx = nullptr;
  explicit Client(int port) {
    ctx = modbus_new_tcp("127.0.0.1", port);
    modbus_set_response_timeout(ctx, 2, 0);
    EXPECT_EQ(modbus_connect(ctx), 0) << modbus_strerror(errno);
  }
  ~Client() {
    modbus_close(ctx);
    modbus_free(ctx);
  }
};

std::uint32_t u32(const std::uint16_t* r) {
  return std::uint32_t{r[0]} << 16 | r[1];
}

class ModbusTest : public ::testing::Test {
 protected:
  UnitCounters counters;
  ConfigStore store;
  std::unique_ptr<ModbusHealthServer> server;

  void start(bool maintenance) {
    ModbusServerConfig cfg;
    cfg.port = 0;
    cfg.maintenance = maintenance;
    server = std::make_unique<ModbusHealthServer>(cfg, counters, store);
    ASSERT_EQ(server->start(), 0) << server->error();
    ASSERT_GT(server->bound_port(), 0);
  }
};

TEST_F(ModbusTest, ReadsHealthInputRegisters) {
  counters.frames_captured = 123'456'789;
  counters.frames_dropped = 7;
  counters.triggers_missing = 3;
  counters.status = 0x5;
  counters.clock_state = 2;
  counters.board_temp_cdeg = -1234;
  counters.ptp_offset_ns = -250;
  start(false);
  Client c(server->bound_port());
  std::array<std::uint16_t, 64> regs{};
  const int n = register_count(RegisterKind::kInput);
  ASSERT_EQ(modbus_read_input_registers(c.ctx, 0, n, regs.data()), n) << modbus_strerror(errno);
  EXPECT_EQ(u32(&regs[input_def(InputField::kFramesCaptured).address]), 123'456'789u);
  EXPECT_EQ(u32(&regs[input_def(InputField::kFramesDropped).address]), 7u);
  EXPECT_EQ(u32(&regs[input_def(InputField::kTriggersMissing).address]), 3u);
  EXPECT_EQ(regs[input_def(InputField::kStatus).address], 0x5);
  EXPECT_EQ(regs[input_def(InputField::kClockState).address], 2);
  EXPECT_EQ(static_cast<std::int16_t>(regs[input_def(InputField::kBoardTempCdeg).address]), -1234);
  EXPECT_EQ(static_cast<std::int32_t>(u32(&regs[input_def(InputField::kPtpOffsetNs).address])),
            -250);
  EXPECT_EQ(regs[input_def(InputField::kFirmwareVersion).address], kFirmwareVersion);
  // Beyond the map: ILLEGAL DATA ADDRESS.
  EXPECT_EQ(modbus_read_input_registers(c.ctx, 0, n + 1, regs.data()), -1);
  EXPECT_EQ(errno, EMBXILADD);
  // Holding registers read back their defaults.
  std::array<std::uint16_t, 16> hold{};
  const int h = register_count(RegisterKind::kHolding);
  ASSERT_EQ(modbus_read_registers(c.ctx, 0, h, hold.data()), h);
  EXPECT_EQ(hold[holding_def(HoldingField::kTriggerRateHz).address],
            holding_def(HoldingField::kTriggerRateHz).default_value);
}

TEST_F(ModbusTest, WritesRefusedOutsideMaintenance) {
  start(false);
  Client c(server->bound_port());
  EXPECT_EQ(modbus_write_register(c.ctx, holding_def(HoldingField::kThresholdDn).address, 50), -1);
  EXPECT_EQ(errno, EMBXSFAIL);
  const std::uint16_t v[2] = {1, 2};
  EXPECT_EQ(modbus_write_registers(c.ctx, 0, 2, v), -1);
  EXPECT_EQ(errno, EMBXSFAIL);
  EXPECT_EQ(store.generation(), 0u);
  EXPECT_EQ(store.get(HoldingField::kThresholdDn),
            holding_def(HoldingField::kThresholdDn).default_value);
  EXPECT_EQ(server->stats().refused_write_locked, 2u);
}

TEST_F(ModbusTest, UnsafeFunctionCodesRefused) {
  start(true);  // even in maintenance mode
  Client c(server->bound_port());
  std::uint16_t out[2] = {1, 2};
  std::uint16_t in[2] = {};
  EXPECT_EQ(modbus_write_and_read_registers(c.ctx, 0, 2, out, 0, 2, in), -1);  // fc 0x17
  EXPECT_EQ(errno, EMBXILFUN);
  EXPECT_EQ(modbus_write_bit(c.ctx, 0, 1), -1);  // fc 0x05
  EXPECT_EQ(errno, EMBXILFUN);
  std::uint8_t bits[8];
  EXPECT_EQ(modbus_read_bits(c.ctx, 0, 8, bits), -1);  // fc 0x01
  EXPECT_EQ(errno, EMBXILFUN);
  EXPECT_EQ(modbus_mask_write_register(c.ctx, 0, 0xFF, 0), -1);  // fc 0x16
  EXPECT_EQ(errno, EMBXILFUN);
  std::uint8_t id[64];
  EXPECT_EQ(modbus_report_slave_id(c.ctx, sizeof id, id), -1);  // fc 0x11
  EXPECT_EQ(errno, EMBXILFUN);
  EXPECT_EQ(store.generation(), 0u);
}

TEST_F(ModbusTest, MaintenanceWritesAreRangeChecked) {
  start(true);
  Client c(server->bound_port());
  const auto thr = holding_def(HoldingField::kThresholdDn).address;
  ASSERT_EQ(modbus_write_register(c.ctx, thr, 55), 1) << modbus_strerror(errno);
  EXPECT_EQ(store.get(HoldingField::kThresholdDn), 55);
  EXPECT_EQ(store.generation(), 1u);
  const auto rate = holding_def(HoldingField::kTriggerRateHz).address;
  EXPECT_EQ(modbus_write_register(c.ctx, rate, 401), -1);
  EXPECT_EQ(errno, EMBXILVAL);
  // Cross rule: 5000 us pulses at 400 Hz would be 200 % duty.
  const std::uint16_t rate_width[2] = {400, 5000};
  ASSERT_EQ(holding_def(HoldingField::kPulseWidthUs).address, rate + 1);
  EXPECT_EQ(modbus_write_registers(c.ctx, rate, 2, rate_width), -1);
  EXPECT_EQ(errno, EMBXILVAL);
  EXPECT_EQ(store.get(HoldingField::kTriggerRateHz), 100);  // all-or-nothing
  // Past the map.
  const auto n = register_count(RegisterKind::kHolding);
  EXPECT_EQ(modbus_write_register(c.ctx, n, 1), -1);
  EXPECT_EQ(errno, EMBXILADD);
  std::uint16_t back = 0;
  ASSERT_EQ(modbus_read_registers(c.ctx, thr, 1, &back), 1);
  EXPECT_EQ(back, 55);
  EXPECT_EQ(store.generation(), 1u);
}

int raw_connect(int port) {
  const int s = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  EXPECT_EQ(connect(s, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
  timeval tv{0, 300'000};
  setsockopt(s, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  return s;
}

TEST_F(ModbusTest, SurvivesMalformedRawRequests) {
  start(true);
  const std::vector<std::vector<std::uint8_t>> bad = {
      {0x00},                                            // truncated MBAP
      {0x00, 0x01, 0x00, 0x00, 0x00, 0x06, 0xFF, 0x03},  // fc, no address
      {0x00, 0x02, 0x00, 0x00, 0xFF, 0xFF, 0xFF, 0x10, 0x00, 0x00, 0x00, 0x7F, 0x02,
       0x00},                                            // byte count lies
      {0x00, 0x03, 0x00, 0x00, 0x00, 0x02, 0xFF, 0x2B},  // unsupported fc 0x2B
      {0x00, 0x04, 0x00, 0x00, 0x00, 0x06, 0xFF, 0x03, 0xFF, 0xFF, 0xFF, 0xFF},  // absurd count
      {0x00, 0x05, 0x00, 0x00, 0x00, 0x09, 0xFF, 0x10, 0x00, 0x05, 0x00, 0x02, 0x03, 0x00, 0x01},
  };
  for (const auto& frame : bad) {
    const int s = raw_connect(server->bound_port());
    ASSERT_EQ(send(s, frame.data(), frame.size(), 0), static_cast<ssize_t>(frame.size()));
    shutdown(s, SHUT_WR);
    std::uint8_t reply[300];
    while (recv(s, reply, sizeof reply, 0) > 0) {
    }  // exceptions, then the server closes: both fine
    close(s);
  }
  std::mt19937 rng(7);
  for (int k = 0; k < 200; ++k) {
    const int s = raw_connect(server->bound_port());
    std::vector<std::uint8_t> frame(static_cast<std::size_t>(1 + rng() % 40));
    for (auto& b : frame)
      b = static_cast<std::uint8_t>(rng());
    if (frame.size() > 7 && k % 2 == 0) {  // plausible MBAP, random PDU
      frame[2] = frame[3] = 0;
      frame[4] = 0;
      frame[5] = static_cast<std::uint8_t>(frame.size() - 6);
    }
    send(s, frame.data(), frame.size(), MSG_NOSIGNAL);
    shutdown(s, SHUT_WR);
    std::uint8_t reply[300];
    while (recv(s, reply, sizeof reply, 0) > 0) {
    }
    close(s);
  }
  // Still serving, and no write was applied by garbage beyond what the table allows.
  Client c(server->bound_port());
  std::uint16_t r[2];
  EXPECT_EQ(modbus_read_input_registers(c.ctx, 0, 2, r), 2) << modbus_strerror(errno);
  std::array<std::uint16_t, 16> hold{};
  const int h = register_count(RegisterKind::kHolding);
  ASSERT_EQ(modbus_read_registers(c.ctx, 0, h, hold.data()), h);
  for (int a = 0; a < h; ++a) {
    const RegisterDef* d = find_register(RegisterKind::kHolding, static_cast<std::uint16_t>(a));
    EXPECT_GE(hold[static_cast<std::size_t>(a)], d->min);
    EXPECT_LE(hold[static_cast<std::size_t>(a)], d->max);
  }
  EXPECT_GT(server->stats().malformed, 0u);
}

TEST_F(ModbusTest, IdleClientsInEverySlotDoNotLockOutANewOne) {
  // Four connections that never send anything hold every slot. Before: the fifth client was
  // closed at accept, so nobody could read the unit's health until one of them left.
  start(false);
  std::vector<int> idle;
  for (int k = 0; k < 4; ++k)
    idle.push_back(raw_connect(server->bound_port()));
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  Client c(server->bound_port());
  std::uint16_t r[2];
  EXPECT_EQ(modbus_read_input_registers(c.ctx, 0, 2, r), 2) << modbus_strerror(errno);
  EXPECT_GE(server->stats().evicted, 1u);
  for (int s : idle)
    close(s);
}

TEST_F(ModbusTest, SlowClientHoldsNobodyElse) {
  // A client sends a valid 12-byte request one byte every 120 ms. Before: libmodbus read the
  // rest of its request with a 0.5 s byte timeout, the one server thread waiting on it, so
  // every other client waited up to 0.5 s a byte. Now each other request is answered at once,
  // and the slow request is closed when it is not whole after request_timeout_ms (1 s).
  start(false);
  std::atomic<bool> done{false};
  std::thread slow([&] {
    const int s = raw_connect(server->bound_port());
    const std::uint8_t req[] = {0, 1, 0, 0, 0, 6, 0xFF, 0x04, 0, 0, 0, 2};
    for (std::uint8_t b : req) {
      if (send(s, &b, 1, MSG_NOSIGNAL) != 1) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(120));
    }
    close(s);
    done = true;
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  Client c(server->bound_port());
  double worst_ms = 0;
  for (int k = 0; k < 10; ++k) {
    const auto t0 = std::chrono::steady_clock::now();
    std::uint16_t r[2];
    EXPECT_EQ(modbus_read_input_registers(c.ctx, 0, 2, r), 2) << modbus_strerror(errno);
    worst_ms = std::max(
        worst_ms,
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  slow.join();
  EXPECT_LT(worst_ms, 100.0) << "another client's request waited";
  EXPECT_EQ(server->stats().timeouts, 1u);
}

TEST_F(ModbusTest, IdentityWritesAreRefusedWhileRunning) {
  // Before: a camera_id written mid-run renamed the camera in its messages at once, and the
  // host applied another camera's calibration to it.
  store.lock_identity();
  start(true);
  Client c(server->bound_port());
  const auto cam = holding_def(HoldingField::kCameraId).address;
  EXPECT_EQ(modbus_write_register(c.ctx, cam, 42), -1);
  EXPECT_EQ(errno, EMBXSBUSY);
  EXPECT_EQ(store.get(HoldingField::kCameraId), 0);
  // The same value (a configuration tool writing the whole block back) is no change.
  const std::uint16_t ids[3] = {0, 0, 1500};
  EXPECT_EQ(modbus_write_registers(c.ctx, 0, 3, ids), 3) << modbus_strerror(errno);
  EXPECT_EQ(store.get(HoldingField::kExposureUs), 1500);
  EXPECT_EQ(server->stats().refused_identity, 1u);
}

TEST_F(ModbusTest, SearchRegionOutsideTheFrameIsRefused) {
  // Before: any region inside the table's 0..4096 was taken: a region past the sensor gave 0
  // marks, silently.
  store.set_limits({640, 480});
  start(true);
  Client c(server->bound_port());
  const auto x = holding_def(HoldingField::kRoiX).address;
  const std::uint16_t past[4] = {600, 0, 100, 0};  // x, y, width, height
  EXPECT_EQ(modbus_write_registers(c.ctx, x, 4, past), -1);
  EXPECT_EQ(errno, EMBXILVAL);
  EXPECT_EQ(modbus_write_register(c.ctx, x, 640), -1) << "x at the frame's width";
  const std::uint16_t inside[4] = {600, 400, 40, 80};
  EXPECT_EQ(modbus_write_registers(c.ctx, x, 4, inside), 4) << modbus_strerror(errno);
  EXPECT_EQ(store.get(HoldingField::kRoiHeight), 80);
}

// Sends a request on a raw connection and returns the whole reply (MBAP length), or nothing
// when the server closed the connection.
std::vector<std::uint8_t> raw_exchange(int s, std::span<const std::uint8_t> request) {
  EXPECT_EQ(send(s, request.data(), request.size(), MSG_NOSIGNAL),
            static_cast<ssize_t>(request.size()));
  std::vector<std::uint8_t> reply;
  std::size_t want = model::kMbapBytes - 1;
  std::uint8_t buf[model::kMaxAduBytes];
  while (reply.size() < want) {
    const ssize_t n = recv(s, buf, want - reply.size(), 0);
    if (n <= 0) return reply;
    reply.insert(reply.end(), buf, buf + n);
    if (reply.size() == 6) want = 6 + (std::size_t{reply[4]} << 8 | reply[5]);
  }
  return reply;
}

TEST_F(ModbusTest, HighBitFunctionCodeGetsAnExceptionReplyWithTheBit) {
  // Before: libmodbus answered fc 0xFF with 0x7F (0xFF + 0x80 cut to 8 bits), 0x01: what a
  // client reads as a normal reply of function 0x7F (found by fuzz_modbus_request).
  start(false);
  const int s = raw_connect(server->bound_port());
  const std::uint8_t request[] = {0x00, 0x03, 0x00, 0x00, 0x00, 0x06,
                                  0xC0, 0xFF, 0x06, 0x00, 0x05, 0x00};
  const std::vector<std::uint8_t> exception = {0x00, 0x03, 0x00, 0x00, 0x00,
                                               0x03, 0xC0, 0xFF, 0x01};
  EXPECT_EQ(raw_exchange(s, request), exception);
  close(s);
  EXPECT_EQ(server->stats().refused_function, 1u);
}

TEST_F(ModbusTest, RequestLongerThanItsFunctionIsIllegalDataValue) {
  // "The implied length is incorrect" (Modbus Application Protocol 1.1b3, 0x03). Before: a
  // write single register with two bytes more was applied and its reply echoed them (14 bytes
  // where 0x06 replies with 12).
  start(true);
  const int s = raw_connect(server->bound_port());
  const std::uint8_t write_long[] = {0x00, 0x07, 0x00, 0x00, 0x00, 0x08, 0xFF,
                                     0x06, 0x00, 0x05, 0x00, 0x32, 0xAB, 0xCD};
  const std::vector<std::uint8_t> illegal_value = {0x00, 0x07, 0x00, 0x00, 0x00,
                                                   0x03, 0xFF, 0x86, 0x03};
  EXPECT_EQ(raw_exchange(s, write_long), illegal_value);
  const std::uint8_t read_long[] = {0x00, 0x08, 0x00, 0x00, 0x00, 0x07, 0xFF,
                                    0x04, 0x00, 0x00, 0x00, 0x02, 0x00};
  const std::vector<std::uint8_t> read_illegal = {0x00, 0x08, 0x00, 0x00, 0x00,
                                                  0x03, 0xFF, 0x84, 0x03};
  EXPECT_EQ(raw_exchange(s, read_long), read_illegal);
  close(s);
  EXPECT_EQ(store.get(HoldingField::kThresholdDn), 0);
  EXPECT_EQ(server->stats().malformed, 2u);
}

TEST_F(ModbusTest, ReadOutsideTheMapIsCounted) {
  // Before: ILLEGAL DATA ADDRESS for a read past the map was the one refusal no counter saw.
  start(false);
  Client c(server->bound_port());
  std::array<std::uint16_t, 64> regs{};
  EXPECT_EQ(
      modbus_read_input_registers(c.ctx, 0, register_count(RegisterKind::kInput) + 1, regs.data()),
      -1);
  EXPECT_EQ(errno, EMBXILADD);
  EXPECT_EQ(modbus_read_registers(c.ctx, 9, 2, regs.data()), -1);
  EXPECT_EQ(server->stats().refused_value, 2u);
}

// One request of a random kind: reads and writes (in and outside the map, values in and out of
// range), other function codes, quantities and lengths that are wrong, and now and then a
// header that is not Modbus TCP.
std::vector<std::uint8_t> random_request(std::mt19937& rng, std::uint16_t tid) {
  const auto pick = [&](int n) { return static_cast<int>(rng() % static_cast<unsigned>(n)); };
  std::vector<std::uint8_t> pdu;
  const auto put16 = [&](int v) {
    pdu.push_back(static_cast<std::uint8_t>(v >> 8));
    pdu.push_back(static_cast<std::uint8_t>(v & 0xFF));
  };
  const int kind = pick(8);
  if (kind <= 1) {  // read, mostly in the map
    pdu.push_back(kind == 0 ? 0x03 : 0x04);
    put16(pick(4) == 0 ? pick(70000) & 0xFFFF : pick(32));
    put16(pick(6) == 0 ? pick(300) : 1 + pick(12));
  } else if (kind == 2) {  // write one register near its range
    pdu.push_back(0x06);
    put16(pick(12));
    put16(pick(3) == 0 ? static_cast<int>(rng() & 0xFFFF) : pick(2100));
  } else if (kind == 3) {  // write several
    const int count = 1 + pick(5);
    pdu.push_back(0x10);
    put16(pick(12));
    put16(count);
    pdu.push_back(static_cast<std::uint8_t>(2 * count));
    for (int k = 0; k < count; ++k)
      put16(pick(3) == 0 ? static_cast<int>(rng() & 0xFFFF) : pick(700));
  } else if (kind == 4) {  // another function code, the high-bit ones included
    const std::uint8_t others[] = {0x01, 0x02, 0x05, 0x0F, 0x11, 0x16, 0x17, 0x2B, 0x80, 0xFF};
    pdu.push_back(others[pick(10)]);
    for (int k = pick(6); k > 0; --k)
      pdu.push_back(static_cast<std::uint8_t>(rng()));
  } else {  // a known function with random bytes: short, long, lying counts
    const std::uint8_t known[] = {0x03, 0x04, 0x06, 0x10};
    pdu.push_back(known[pick(4)]);
    for (int k = pick(12); k > 0; --k)
      pdu.push_back(static_cast<std::uint8_t>(rng()));
  }
  std::vector<std::uint8_t> adu = {
      static_cast<std::uint8_t>(tid >> 8),       static_cast<std::uint8_t>(tid & 0xFF), 0, 0, 0,
      static_cast<std::uint8_t>(pdu.size() + 1), static_cast<std::uint8_t>(rng())};
  if (pick(100) == 0) adu[3] = 1;  // protocol id 1: not Modbus TCP
  adu.insert(adu.end(), pdu.begin(), pdu.end());
  return adu;
}

TEST_F(ModbusTest, ThousandsOfRandomRequestsAreEachAnsweredAndCounted) {
  // 2000 well-formed and malformed requests from a raw client, one at a time: each gets the
  // reply of the model of a correct server (modbus_model.hpp: the protocol and docs/modbus.md),
  // a header that is not Modbus TCP gets the connection closed; then a libmodbus client still
  // reads the right values, and the counters account for every request and refusal.
  store.lock_identity();
  store.set_limits({640, 480});
  start(true);
  model::Server::Holding holding{};
  store.read_all(holding);
  model::Server expected(true, {640, 480}, holding, store.generation());
  std::mt19937 rng(20240611);
  int s = raw_connect(server->bound_port());
  int closed = 0;
  for (int k = 0; k < 2000; ++k) {
    const std::vector<std::uint8_t> request = random_request(rng, static_cast<std::uint16_t>(k));
    const model::Framing framing = model::frame_stream(request);
    ASSERT_EQ(framing.requests.size() + (framing.bad_header ? 1 : 0), 1u);
    const std::vector<std::uint8_t> got = raw_exchange(s, request);
    if (framing.bad_header) {
      EXPECT_TRUE(got.empty()) << "request " << k;
      close(s);
      s = raw_connect(server->bound_port());
      ++closed;
      continue;
    }
    const model::Reply want = expected.answer(framing.requests[0]);
    ASSERT_TRUE(model::same_reply(got, want)) << "request " << k << ": fc " << int{request[7]};
  }
  close(s);
  EXPECT_GT(closed, 0);
  Client c(server->bound_port());
  std::array<std::uint16_t, 16> hold{};
  const int h = register_count(RegisterKind::kHolding);
  ASSERT_EQ(modbus_read_registers(c.ctx, 0, h, hold.data()), h) << modbus_strerror(errno);
  for (int a = 0; a < h; ++a)
    EXPECT_EQ(hold[static_cast<std::size_t>(a)], expected.holding()[static_cast<std::size_t>(a)]);
  EXPECT_EQ(store.generation(), expected.generation());
  const ModbusServerStats st = server->stats();
  const model::Counts& n = expected.counts();
  EXPECT_GT(n.writes_accepted, 0u);
  EXPECT_GT(n.refused_identity + n.refused_value + n.refused_function + n.malformed, 0u);
  EXPECT_EQ(st.requests, n.requests + 1);  // + the libmodbus read
  EXPECT_EQ(st.refused_function, n.refused_function);
  EXPECT_EQ(st.refused_value, n.refused_value);
  EXPECT_EQ(st.refused_identity, n.refused_identity);
  EXPECT_EQ(st.refused_write_locked, 0u);
  EXPECT_EQ(st.writes_accepted, n.writes_accepted);
  EXPECT_EQ(st.malformed, n.malformed + static_cast<std::uint64_t>(closed));
}

TEST(ConfigStore, MultiRegisterWriteIsSeenWhole) {
  // One thread writes (rate, width) pairs (100 Hz, 100 us) and (400 Hz, 2000 us), another
  // takes snapshots: every snapshot holds one of the written pairs, never a mix (400 Hz with
  // 100 us, or 100 Hz with 2000 us), which reading field by field can give.
  ConfigStore store;
  const auto rate = holding_def(HoldingField::kTriggerRateHz).address;
  std::atomic<bool> stop{false};
  std::thread writer([&] {
    const std::uint16_t a[2] = {400, 2000}, b[2] = {100, 100};
    for (int k = 0; !stop.load(); ++k)
      ASSERT_EQ(store.write(rate, std::span<const std::uint16_t>(k % 2 ? b : a, 2), nullptr), 0);
  });
  while (store.generation() < 2)
    std::this_thread::yield();
  // Until each written pair was seen 1000 times (the two threads interleaved), at most 5 s.
  long torn = 0, seen_a = 0, seen_b = 0, reads = 0;
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while ((seen_a < 1000 || seen_b < 1000) && std::chrono::steady_clock::now() < until) {
    const ConfigStore::Values v = store.snapshot();
    const auto r = v[static_cast<std::size_t>(HoldingField::kTriggerRateHz)];
    const auto w = v[static_cast<std::size_t>(HoldingField::kPulseWidthUs)];
    seen_a += r == 400 && w == 2000;
    seen_b += r == 100 && w == 100;
    ++reads;
  }
  torn = reads - seen_a - seen_b;
  stop = true;
  writer.join();
  EXPECT_EQ(torn, 0) << "of " << reads << " snapshots";
  EXPECT_GE(std::min(seen_a, seen_b), 1000) << "the writer ran during the reads";
}

TEST(RegisterMap, TableIsConsistent) {
  EXPECT_EQ(check_register_map(), "");
}

TEST(RegisterMap, DocumentationMatchesTheTable) {
  const std::filesystem::path doc = std::filesystem::path(STORETRACK_SOURCE_DIR) / "docs/modbus.md";
  std::ifstream in(doc);
  ASSERT_TRUE(in.good()) << doc << " missing: storetrack-unit modbus-doc > docs/modbus.md";
  std::stringstream ss;
  ss << in.rdbuf();
  EXPECT_EQ(ss.str(), render_register_map_markdown())
      << "docs/modbus.md is stale: regenerate with `storetrack-unit modbus-doc > docs/modbus.md`";
}

TEST(RegisterMap, BoardTemperatureFromThermalZones) {
  namespace fs = std::filesystem;
  const fs::path root = fs::temp_directory_path() / ("st_thermal_" + std::to_string(getpid()));
  fs::create_directories(root / "thermal_zone0");
  fs::create_directories(root / "thermal_zone1");
  std::ofstream(root / "thermal_zone0" / "temp") << "41500\n";
  std::ofstream(root / "thermal_zone1" / "temp") << "52250\n";
  EXPECT_EQ(read_board_temp_cdeg(root.string()), 5225);
  fs::remove_all(root);
  EXPECT_EQ(read_board_temp_cdeg("/nonexistent"), INT16_MIN);
}

// The sampler publishes what the sensor reads: at start, then once per period (a changed
// temperature shows within about one period), and stops promptly.
TEST(BoardTemperatureSampler, PublishesTheSensorReadingEveryPeriod) {
  namespace fs = std::filesystem;
  const fs::path root = fs::temp_directory_path() / ("st_sampler_" + std::to_string(getpid()));
  fs::create_directories(root / "thermal_zone0");
  std::ofstream(root / "thermal_zone0" / "temp") << "41500\n";
  std::atomic<std::int16_t> published{INT16_MIN};
  BoardTemperatureSampler sampler(root.string(), 20, published);
  const auto wait_for = [&](std::int16_t value) {
    for (int i = 0; i < 200 && published.load() != value; ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    return published.load();
  };
  sampler.start();
  EXPECT_EQ(wait_for(4150), 4150);
  std::ofstream(root / "thermal_zone0" / "temp") << "63010\n";
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(wait_for(6301), 6301);
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::milliseconds(100));
  const auto t1 = std::chrono::steady_clock::now();
  sampler.stop();
  EXPECT_LT(std::chrono::steady_clock::now() - t1, std::chrono::milliseconds(50));
  EXPECT_GE(sampler.samples(), 2u);
  fs::remove_all(root);
}

}  // namespace
}  // namespace storetrack::health
