// The unit's per-frame path allocates nothing: the whole capture loop (acquire -> pair ->
// centroid -> encode -> send -> health) runs in-process on the simulator with a sim trigger, a
// UDP link to a receiver here and a 10 ms health period, under an allocator that counts every
// allocation function (storetrack::counting_allocator). Only the capture thread's allocations
// are counted: the board-temperature sampler reads sysfs through std::filesystem on its own.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <new>
#include <span>
#include <string>
#include <thread>
#include <variant>

#include "storetrack/msg/udp_codec.hpp"
#include "storetrack/testing/counting_allocator.hpp"
#include "unit_runner.hpp"

namespace storetrack {
namespace {

using testing::allocation_count;

// Each allocation function counts once (before: only operator new and new[] were counted, so
// a malloc, an aligned or a nothrow new on the frame path went unseen).
TEST(CountingAllocator, CountsEveryAllocationFunction) {
  // volatile: the compiler may not elide an allocation whose pointer escapes.
  void* volatile p = nullptr;
  const auto counts = [&](auto&& allocate, auto&& release) {
    const long before = allocation_count();
    p = allocate();
    const long n = allocation_count() - before;
    release(p);
    return n;
  };
  EXPECT_EQ(counts([] { return ::operator new(24); }, [](void* q) { ::operator delete(q); }), 1);
  EXPECT_EQ(counts([] { return ::operator new(24, std::nothrow); },
                   [](void* q) { ::operator delete(q, std::nothrow); }),
            1);
  EXPECT_EQ(counts([] { return ::operator new (256, std::align_val_t{64}); },
                   [](void* q) { ::operator delete (q, std::align_val_t{64}); }),
            1);
  EXPECT_EQ(counts([] { return ::operator new[](256, std::align_val_t{64}, std::nothrow); },
                   [](void* q) { ::operator delete[](q, std::align_val_t{64}, std::nothrow); }),
            1);
  if (!testing::c_allocator_counted()) GTEST_SKIP() << "malloc belongs to the sanitizer here";
  EXPECT_EQ(counts([] { return std::malloc(24); }, [](void* q) { std::free(q); }), 1);
  EXPECT_EQ(counts([] { return std::calloc(3, 8); }, [](void* q) { std::free(q); }), 1);
  EXPECT_EQ(counts([] { return std::aligned_alloc(64, 128); }, [](void* q) { std::free(q); }), 1);
  void* block = std::malloc(16);
  const long before = allocation_count();
  p = std::realloc(block, 4096);
  EXPECT_EQ(allocation_count() - before, 1);
  std::free(p);
  // The counter of one thread sees that thread's allocations only (std::thread's own state is
  // allocated by the thread that starts it: counted before `mine`).
  std::atomic<int> step{0};
  std::thread other([&] {
    while (step.load() != 1)
      std::this_thread::yield();
    void* volatile q = std::malloc(32);
    std::free(q);
    step = 2;
  });
  const long mine = testing::this_thread_allocations().load();
  const long all = allocation_count();
  step = 1;
  while (step.load() != 2)
    std::this_thread::yield();
  EXPECT_EQ(testing::this_thread_allocations().load(), mine);
  EXPECT_EQ(allocation_count() - all, 1);
  other.join();
}

struct Receiver {
  int fd = -1;
  int port = 0;
  long observations = 0;
  long health = 0;
  long decode_errors = 0;
  std::uint32_t last_seq = 0;
  long seq_gaps = 0;

  Receiver() {
    fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
    socklen_t len = sizeof a;
    getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
    port = ntohs(a.sin_port);
    const int rcvbuf = 8 << 20;
    setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof rcvbuf);
  }
  ~Receiver() { close(fd); }
  /// Takes what arrived within timeout_ms; false when nothing did.
  bool poll_once(int timeout_ms) {
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, timeout_ms) != 1) return false;
    std::uint8_t buf[2048];
    const ssize_t n = recv(fd, buf, sizeof buf, 0);
    msg::AnyMessage any;
    if (n <= 0 ||
        msg::decode_datagram(std::span<const std::uint8_t>(buf, static_cast<std::size_t>(n)),
                             any) != msg::DecodeError::kNone) {
      ++decode_errors;
      return true;
    }
    if (const auto* o = std::get_if<msg::MarkObservations>(&any)) {
      if (observations > 0 && o->trigger_seq != last_seq + 1) ++seq_gaps;
      last_seq = o->trigger_seq;
      ++observations;
    } else if (std::holds_alternative<msg::UnitHealth>(any)) {
      ++health;
    }
    return true;
  }
};

TEST(UnitAllocations, SteadyStateLoopAllocatesNothing) {
  Receiver rx;
  unit::UnitConfig config;
  config.source = unit::SourceType::kSim;
  config.sim.scenario = std::string(STORETRACK_SCENARIO_DIR) + "/pendulum.json";  // 480 exposures
  config.sim.camera_index = 0;
  config.trigger.mode = unit::TriggerMode::kSim;
  link::UdpLinkConfig udp;
  udp.destination = "127.0.0.1:" + std::to_string(rx.port);
  config.udp.push_back(udp);
  config.health_period_ms = 10;
  config.modbus_enabled = false;
  unit::UnitRunner runner(config, unit::simulator_camera_factory());
  std::string error;
  ASSERT_EQ(runner.setup(error), unit::kExitOk) << error;

  std::atomic<const std::atomic<long>*> capture_allocations{nullptr};
  std::atomic<bool> stop{false};
  int exit_code = -1;
  std::thread capture([&] {
    capture_allocations = &testing::this_thread_allocations();
    exit_code = runner.run(stop);
  });
  const long warm_up = 80, measured = 300;
  long at_start = -1, at_end = -1, health_start = 0, health_end = 0, observations_end = 0;
  while (rx.poll_once(2000)) {
    if (at_start < 0 && rx.observations >= warm_up) {
      at_start = capture_allocations.load()->load(std::memory_order_relaxed);
      health_start = rx.health;
    }
    if (at_end < 0 && rx.observations >= warm_up + measured) {
      at_end = capture_allocations.load()->load(std::memory_order_relaxed);
      health_end = rx.health;
      observations_end = rx.observations;
      stop = true;  // before the thread (and its counter) ends
      break;
    }
  }
  stop = true;
  capture.join();
  runner.shutdown();
  ASSERT_GE(at_start, 0) << "no warm-up: " << rx.observations << " observations";
  ASSERT_GE(at_end, 0) << "only " << rx.observations << " observations";
  EXPECT_EQ(exit_code, unit::kExitOk);
  EXPECT_EQ(rx.decode_errors, 0);
  EXPECT_EQ(rx.seq_gaps, 0) << "every exposure sent, in order";
  std::printf(
      "capture thread: %ld allocations over %ld frames and %ld health reports "
      "(after %ld frames of warm-up; malloc family %s)\n",
      at_end - at_start, observations_end - warm_up, health_end - health_start, warm_up,
      testing::c_allocator_counted() ? "counted" : "not counted (sanitizer)");
  EXPECT_GT(health_end - health_start, 5) << "the health path ran inside the measured window";
  EXPECT_EQ(at_end - at_start, 0);
}

}  // namespace
}  // namespace storetrack
